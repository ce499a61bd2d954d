"""Scoped torch thread counts: ``torch.set_num_threads`` is process-wide, so every caller that
needs a count sets it for a block and puts the previous value back afterwards."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """Run the block with ``threads`` intra-op torch threads (``None``: leave it as it is),
    then restore the previous count, also when the block raises."""
    if not threads:
        yield
        return
    import torch  # here: a caller without a count never needs torch

    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)
