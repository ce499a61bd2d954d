"""Waits on subprocesses bounded by progress, not by a guess of the machine's speed.

A run that still advances (a file under one of the watched paths grows, appears or is
rewritten) keeps its time; one that writes nothing for ``stall_s`` seconds is a failure,
reported with the tail of its log. CI machines may be loaded several times over: a fixed
timeout that holds on an idle machine fails there, a stall limit does not.
"""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import pytest

#: Seconds without any write under the watched paths after which a wait fails. The longest
#: silent stretch of the runs waited on is a process start (torch import, Ray worker start),
#: well under a minute on an idle 2-core machine.
STALL_S = 240.0


def _signature(paths: Iterable[Path]) -> tuple:
    """(path, size, mtime) of every file under ``paths`` (files or folders; missing: none)."""
    seen = []
    for root in paths:
        root = Path(root)
        if root.is_file():
            files = [root]
        elif root.is_dir():
            files = [Path(d) / f for d, _, names in os.walk(root) for f in names]
        else:
            files = []
        for f in files:
            try:
                st = f.stat()
            except FileNotFoundError:  # renamed away between the walk and the stat
                continue
            seen.append((str(f), st.st_size, st.st_mtime_ns))
    return tuple(sorted(seen))


def wait_until(
    done: Callable[[], bool],
    watched: Iterable[Path],
    what: str,
    proc: subprocess.Popen | None = None,
    log: Path | None = None,
    stall_s: float = STALL_S,
    poll_s: float = 0.05,
) -> None:
    """Return once ``done()`` is true; fail when ``proc`` (if given) ends first, or when
    nothing under ``watched`` changed for ``stall_s`` seconds."""
    watched = list(watched)
    last, since = _signature(watched), time.monotonic()
    checked = since
    while not done():
        if proc is not None and proc.poll() is not None and not done():
            pytest.fail(f"process ended (rc {proc.returncode}) before {what}:\n{_tail(log)}")
        now = time.monotonic()
        if now - checked >= 1.0:  # look for writes once a second
            checked, sig = now, _signature(watched)
            if sig != last:
                last, since = sig, now
            elif now - since > stall_s:
                pytest.fail(f"no progress for {stall_s:.0f} s waiting for {what}:\n{_tail(log)}")
        time.sleep(poll_s)


def wait_process(
    proc: subprocess.Popen,
    watched: Iterable[Path],
    what: str,
    log: Path | None = None,
    stall_s: float = STALL_S,
) -> int:
    """``proc``'s exit code, waiting as long as it makes progress (see the module doc); a
    stalled process is killed before the test fails."""
    try:
        wait_until(lambda: proc.poll() is not None, watched, what, None, log, stall_s, 0.2)
    except BaseException:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        raise
    return proc.returncode


def _tail(log: Path | None, chars: int = 3000) -> str:
    if log is None or not Path(log).is_file():
        return "(no log)"
    return Path(log).read_text(errors="replace")[-chars:]
