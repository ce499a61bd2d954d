"""The manifest of a folder output: which top-level entries slimseg wrote there, and what.

Every folder output holds :data:`MANIFEST` (``.slimseg-outputs.json``)::

    {"written_by": "slimseg dynamic", "format": 2,
     "entries": {"masks": {"kind": "dir", "size": 81920, "sha256": "…"},
                 "frames.csv": {"kind": "file", "size": 2210, "sha256": "…"},
                 "results.csv": null}}

Each entry is one name inside the folder (no ``/``, no ``..``, nothing absolute) with a record
of what was written: its kind (``file``, ``dir``, ``link``), its size in bytes (a folder: the
sum of its files) and a SHA-256 digest of its content (a folder: of every path, kind and file
digest inside it; a symlink: of its target text, never followed). ``null`` marks an entry a
command announced before writing it (a resumable sweep, an interrupted ``data synth``): only a
command that writes that very name may take it over (:func:`entry_problems`). A manifest of
an older slimseg (``"entries": [names]``) reads as all-``null``.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
from collections.abc import Collection, Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

MANIFEST = ".slimseg-outputs.json"  # in every folder output: what slimseg wrote there
FORMAT = 2
MAX_MANIFEST_BYTES = 4 << 20  # a manifest lists top-level names: a few KB
_CHUNK = 1 << 20


@dataclass(frozen=True)
class Record:
    """What slimseg wrote under one name: kind, bytes and SHA-256 digest."""

    kind: str
    size: int
    sha256: str

    def to_json(self) -> dict[str, object]:
        return {"kind": self.kind, "size": self.size, "sha256": self.sha256}


Entries = dict[str, Record | None]  # name -> record (None: announced, not yet recorded)


def confined_name(name: object) -> bool:
    """``name`` is one entry of its folder: a non-empty string with no separator, not ``.``
    or ``..``, no NUL (so joined to the folder it can never point outside it)."""
    return (
        isinstance(name, str)
        and name not in ("", ".", "..")
        and "/" not in name
        and "\\" not in name
        and "\0" not in name
    )


def _file_digest(path: Path, h: hashlib._Hash) -> int:
    """Feed ``path``'s bytes (opened without following a symlink) to ``h``; its size."""
    size = 0
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
            raise OSError(f"{path}: not a regular file")
        while chunk := f.read(_CHUNK):
            h.update(chunk)
            size += len(chunk)
    return size


def record(path: Path) -> Record | None:
    """The :class:`Record` of what is at ``path`` now (symlinks not followed), ``None`` when
    nothing is there or it is neither a file, a folder nor a symlink (a FIFO, a device)."""
    try:
        st = os.lstat(path)
    except OSError:
        return None
    h = hashlib.sha256()
    if stat.S_ISLNK(st.st_mode):
        target = os.fsencode(os.readlink(path))
        h.update(target)
        return Record("link", len(target), h.hexdigest())
    if stat.S_ISREG(st.st_mode):
        return Record("file", _file_digest(path, h), h.hexdigest())
    if not stat.S_ISDIR(st.st_mode):
        return None
    total = 0
    for root, dirs, files in _walk(path):
        rel = os.path.relpath(root, path)
        for name in sorted(files + [d for d in dirs if os.path.islink(os.path.join(root, d))]):
            inner = record(Path(root, name))
            if inner is None:
                return None  # something slimseg never writes (a FIFO) lies inside
            h.update(f"{os.path.join(rel, name)}\0{inner.kind}\0{inner.sha256}\n".encode())
            total += inner.size
        h.update(f"{rel}/\0dir\n".encode())
    return Record("dir", total, h.hexdigest())


def _walk(top: Path) -> Iterator[tuple[str, list[str], list[str]]]:
    """``os.walk(top)`` top-down with each folder's subfolders sorted, without recursion (a
    folder nested 1,200 deep ran Python 3.11's recursive ``os.walk`` out of stack); symlinked
    folders are listed, not entered."""
    stack = [str(top)]
    while stack:
        root = stack.pop()
        try:
            with os.scandir(root) as it:
                entries = list(it)
        except OSError:  # as os.walk: a folder that cannot be listed is passed over
            continue
        dirs, files = [], []
        for e in entries:
            try:
                is_dir = e.is_dir()
            except OSError:
                is_dir = False
            (dirs if is_dir else files).append(e.name)
        dirs.sort()
        yield root, dirs, files
        stack.extend(os.path.join(root, d) for d in reversed(dirs)
                     if not os.path.islink(os.path.join(root, d)))  # fmt: skip


def read_entries(folder: Path) -> Entries | None:
    """The entries of ``folder``'s manifest, or ``None`` without a readable one (missing,
    too large, malformed or listing anything but names). Names are returned as written:
    :func:`entry_problems` refuses those that are not :func:`confined_name`."""
    path = folder / MANIFEST
    try:
        if not path.is_file() or path.is_symlink() or path.stat().st_size > MAX_MANIFEST_BYTES:
            return None
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    entries = data.get("entries") if isinstance(data, dict) else None
    if isinstance(entries, list) and all(isinstance(e, str) for e in entries):
        return dict.fromkeys(entries)  # an older slimseg's: names without records
    if not isinstance(entries, dict):
        return None
    out: Entries = {}
    for name, rec in entries.items():
        if rec is None:
            out[name] = None
            continue
        if not isinstance(rec, dict):
            return None
        kind, size, digest = rec.get("kind"), rec.get("size"), rec.get("sha256")
        if kind not in ("file", "dir", "link") or not isinstance(digest, str):
            return None
        if not isinstance(size, int) or isinstance(size, bool) or size < 0:
            return None
        out[name] = Record(kind, size, digest)
    return out


def manifest_text(command: str, entries: Mapping[str, Record | None]) -> str:
    """The manifest of a folder holding ``entries`` written by ``command``."""
    body = {n: (r.to_json() if r else None) for n, r in sorted(entries.items()) if n != MANIFEST}
    doc = {"written_by": f"slimseg {command}", "format": FORMAT, "entries": body}
    return json.dumps(doc, indent=1) + "\n"


def record_entries(folder: Path, names: Iterable[str], announced: Collection[str] = ()) -> Entries:
    """Records of ``names`` as they are now in ``folder``; a name in ``announced`` that does
    not exist yet is kept as ``None`` (to be written), any other missing name is dropped."""
    out: Entries = {}
    for name in names:
        if name == MANIFEST or not confined_name(name):
            continue
        rec = record(folder / name)
        if rec is not None or name in announced:
            out[name] = rec
    return out


def entry_problems(folder: Path, own: Collection[str] = ()) -> list[str]:
    """Why slimseg may not remove or replace what ``folder``'s manifest lists, one short
    phrase per entry (empty: every listed entry is slimseg's and unchanged).

    An entry is refused when its name is not confined to the folder (``../x``, ``/etc``), when
    it was recorded and what is there now differs (size, kind or content digest), or when it
    was only announced (``null``, or an older manifest) and its name is not in ``own`` (the
    names the calling command itself writes). An announced entry that is missing is fine."""
    entries = read_entries(folder) or {}
    problems: list[str] = []
    for name, rec in sorted(entries.items()):
        if not confined_name(name):
            problems.append(f"{name!r} (not a name inside the folder)")
            continue
        if not os.path.lexists(folder / name):
            continue  # nothing to remove
        if rec is None:
            if name not in own:
                problems.append(f"{name} (listed without a record of what was written)")
            continue
        if record(folder / name) != rec:
            problems.append(f"{name} (changed since slimseg wrote it)")
    return problems
