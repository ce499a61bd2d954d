"""Inputs are regular files: FIFOs, devices and sockets are refused before they are opened.

A ``.bag`` linked to ``/dev/zero`` never ends, and a FIFO named ``.mcap`` blocks its reader
until another process writes; neither is a file a user meant to give. :func:`check_regular`
follows symlinks (a link to a real file is fine) and refuses anything that is not a regular
file in one line naming it; :func:`read_capped` reads a small text input (YAML, JSON, TUM
lists) after that check, refusing one larger than its cap before reading it.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from slimseg.errors import SlimsegError

_KINDS = (
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISDIR, "a folder"),
)


def check_regular(path: str | Path, what: str = "input") -> os.stat_result:
    """``os.stat`` of ``path`` when it is a regular file (symlinks followed); else
    ``SlimsegError`` naming it and what it is. A missing path raises ``FileNotFoundError``
    (the CLI prints it in one line)."""
    st = os.stat(path)
    if not stat.S_ISREG(st.st_mode):
        kind = next((name for test, name in _KINDS if test(st.st_mode)), "not a regular file")
        raise SlimsegError(f"{path}: the {what} is {kind}, not a regular file: give a file")
    return st


def read_capped(path: str | Path, what: str, cap: int) -> bytes:
    """The bytes of the regular file ``path``; ``SlimsegError`` naming it when it is not a
    regular file (:func:`check_regular`) or holds more than ``cap`` bytes (checked before the
    read, and again while reading, in case it grows)."""
    st = check_regular(path, what)
    if st.st_size > cap:
        raise SlimsegError(
            f"{path}: the {what} holds {st.st_size} bytes, over the {cap}-byte limit for it"
        )
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):  # swapped since the check
            raise SlimsegError(f"{path}: the {what} is not a regular file: give a file")
        data = f.read(cap + 1)
    if len(data) > cap:
        raise SlimsegError(f"{path}: the {what} grew over the {cap}-byte limit while read")
    return data
