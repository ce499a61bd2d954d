"""Thread counts: bounded by the CPU cores this process may use, and scoped.

``torch.set_num_threads`` is process-wide, so every caller that needs a count sets it for a
block and puts the previous value back afterwards (:func:`torch_threads`). A count above the
cores the process may run on (:func:`available_cpus`: its CPU affinity, else ``os.cpu_count``)
buys nothing and can start tens of thousands of threads (``--threads 10000``: onnxruntime,
OpenMP and torch pools each of that size), so :func:`check_threads` refuses it in one line
before any pool is made.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

from slimseg.errors import SlimsegError


def available_cpus() -> int:
    """The CPU cores this process may run on (its affinity mask where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def check_threads(threads: int | None, where: str = "threads") -> int | None:
    """``threads`` when it is ``None``, 0 (the runtime's default) or 1..:func:`available_cpus`;
    else ``SlimsegError`` naming ``where`` (an option or argument) and the limit."""
    if threads is None or threads == 0:
        return threads
    cpus = available_cpus()
    if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= cpus:
        raise SlimsegError(
            f"{where} {threads!r}: give a whole number from 1 to {cpus} (the CPU cores this "
            "process may use), or 0 for the default"
        )
    return threads


@contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """Run the block with ``threads`` intra-op torch threads (``None`` or 0: leave it as it
    is; more than :func:`available_cpus` is refused), then restore the previous count, also
    when the block raises."""
    if not check_threads(threads):
        yield
        return
    import torch  # here: a caller without a count never needs torch

    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)
