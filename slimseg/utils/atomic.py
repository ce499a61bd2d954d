"""Atomic outputs: every file goes to a temporary name in its folder, then ``os.replace``;
every folder output is built in a temporary folder beside it, then moved into place.

A reader never sees a half-written file, and an interrupted write leaves the previous version
(or nothing) in place. ``atomic_path`` serves writers that take a path (``torch.save``,
``Figure.savefig``, ``cv2.imwrite``); the ``write_*`` helpers cover the common formats;
``staged_dir`` serves commands whose output is a folder (``slimseg dynamic``'s ``masks/`` and
``frames.csv``, ``predict``'s files, ``slam-eval``'s ``trajectories/``): the folder appears
complete or not at all, replaces only a folder slimseg wrote (:mod:`slimseg.utils.outputs`),
and a command that fails midway leaves it as it was. :func:`write_manifest` and
:func:`add_to_manifest` write the manifest that lists a folder's entries as slimseg's.
"""

from __future__ import annotations

import ctypes
import errno
import json
import os
import secrets
import shutil
import socket
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import yaml

from slimseg.errors import SlimsegError
from slimseg.utils.manifest import (
    MANIFEST,
    confined_name,
    entry_problems,
    manifest_text,
    read_entries,
    record_entries,
)
from slimseg.utils.outputs import claim_folder, foreign_entries, named_folder, refuse_inputs
from slimseg.utils.text import printable


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix, so format sniffing works); on a
    clean exit it replaces ``path``, on an exception it is removed. Creates the folder.

    The temporary name holds the host, the process id and a random token, so writers on
    several machines sharing one folder (NFS, a sweep across a cluster) never share it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{_tag()}.tmp{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _tag() -> str:
    return f"{socket.gethostname()}.{os.getpid()}.{secrets.token_hex(4)}"


def stage_name(name: str) -> str:
    """A temporary name for a staged output beside ``name`` (``.NAME.<host.pid.token>.tmp``)."""
    return f".{name}.{_tag()}.tmp"


@contextmanager
def staged_dir(
    path: str | Path,
    option: str = "--out",
    command: str = "",
    inputs: Mapping[str, str | Path | Iterable[str | Path] | None] | None = None,
) -> Iterator[Path]:
    """A folder output that appears complete or not at all, and replaces only slimseg's own.

    Before anything: ``SlimsegError`` naming ``option`` when ``path`` is a file, holds entries
    slimseg did not write (:func:`slimseg.utils.outputs.claim_folder`) or is or contains one
    of ``inputs`` (``{option: path(s)}``, :func:`~slimseg.utils.outputs.refuse_inputs`).
    Then yields a fresh temporary folder beside ``path`` (``.NAME.<host.pid.token>.tmp``);
    the caller writes everything there. On a clean exit the manifest
    (:data:`~slimseg.utils.outputs.MANIFEST`, naming ``command``) is added and the whole
    folder takes ``path``'s place in one rename (an atomic exchange with an earlier run's
    folder where the kernel offers one), so no file of an earlier run stays and no reader
    sees half a run. A file a user dropped into ``path`` while the command ran is carried
    over, never deleted. A run that wrote nothing changes nothing. On an exception the
    temporary folder (and any parent folder this call created) is removed and ``path`` is
    as before."""
    path = named_folder(path, option)
    if path.is_symlink():
        path = path.resolve()  # replace the folder the link points at, keep the link
    refuse_inputs(path, option, inputs or {}, folder=True)
    claim_folder(path, option)
    created = [p for p in (path.parent, *path.parent.parents) if not p.exists()]
    path.parent.mkdir(parents=True, exist_ok=True)
    stage = path.with_name(stage_name(path.name))
    try:
        stage.mkdir()
        yield stage
        if any(stage.iterdir()):  # a run that wrote nothing leaves no folder behind
            _publish(stage, path, command or "command")
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        for p in created:  # innermost first; only folders this call made and left empty
            if p.is_dir() and not path.exists() and not any(p.iterdir()):
                p.rmdir()


def _publish(stage: Path, path: Path, command: str) -> None:
    """Move the finished ``stage`` to ``path``; an earlier folder there ends up in ``stage``
    (deleted by the caller) after its foreign entries (a race) moved into the new one."""
    foreign = foreign_entries(path) if path.is_dir() else []  # appeared while it ran
    changed = entry_problems(path) if path.is_dir() else []  # edited while it ran
    if changed:
        raise SlimsegError(
            f"{path}: {', '.join(printable(c) for c in changed)} while the command ran; move "
            "it and run again"
        )
    taken = [name for name in foreign if os.path.lexists(stage / name)]
    if taken:  # the user's entry would be replaced: keep it, and --out as it was
        raise SlimsegError(
            f"{path}: {', '.join(taken)} appeared while the command ran and would be "
            "replaced; move it and run again"
        )
    write_manifest(stage, command)  # lists what the command wrote, nothing else
    for name in foreign:  # the user's: carried into the new folder
        os.replace(path / name, stage / name)
    if not path.exists():
        os.rename(stage, path)
    elif not _exchange(stage, path):
        old = path.with_name(f".{path.name}.{_tag()}.old")
        os.replace(path, old)
        os.replace(stage, path)
        os.replace(old, stage)


_AT_FDCWD = -100
_RENAME_NOREPLACE = 1
_RENAME_EXCHANGE = 2


def _renameat2(a: Path, b: Path, flags: int) -> bool:
    """Linux ``renameat2(a, b, flags)``; ``False`` where the C library or the file system does
    not offer it; ``OSError`` (``FileExistsError`` for ``EEXIST``) on any other failure."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), flags) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EXDEV):
        return False
    raise OSError(err, os.strerror(err), str(a), None, str(b))


def publish_new(src: Path, dst: Path, option: str = "--out") -> None:
    """Move the finished output ``src`` (a file or a folder) to ``dst``, which must not exist:
    never replaces anything that appeared at ``dst`` meanwhile. Linux: one
    ``renameat2(RENAME_NOREPLACE)``; elsewhere a file is hard-linked (which fails when ``dst``
    exists) and its staged name removed, a folder renamed after a last check.
    ``SlimsegError`` naming ``option`` when ``dst`` exists."""
    taken = SlimsegError(
        f"{option} {dst} appeared while the command ran; it was kept: move it and run again"
    )
    try:
        if _renameat2(src, dst, _RENAME_NOREPLACE):
            return
        if src.is_dir() and not src.is_symlink():
            if os.path.lexists(dst):
                raise taken
            os.rename(src, dst)  # onto an existing non-empty folder this fails too
            return
        try:
            os.link(src, dst, follow_symlinks=False)
        except FileExistsError:
            raise
        except OSError:  # no hard links on this file system: the last check, then rename
            if os.path.lexists(dst):
                raise taken from None
            os.rename(src, dst)
            return
        os.unlink(src)
    except FileExistsError:
        raise taken from None


def _exchange(a: Path, b: Path) -> bool:
    """Swap ``a`` and ``b`` in one step (Linux ``renameat2(RENAME_EXCHANGE)``); ``False``
    where the C library or the file system does not offer it."""
    return _renameat2(a, b, _RENAME_EXCHANGE)


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text(path: str | Path, text: str) -> Path:
    """UTF-8 text, atomically."""
    return write_bytes(path, text.encode("utf-8"))


def write_json(path: str | Path, obj: object, indent: int | None = None) -> Path:
    """JSON (compact unless ``indent``), atomically."""
    separators = (",", ":") if indent is None else None
    return write_text(path, json.dumps(obj, indent=indent, separators=separators))


def write_yaml(path: str | Path, obj: object) -> Path:
    """YAML (keys in insertion order), atomically."""
    return write_text(path, yaml.safe_dump(obj, sort_keys=False, default_flow_style=None))


def write_png(path: str | Path, image: np.ndarray) -> Path:
    """``uint8 [H, W, 3]`` RGB (stored as BGR, like every cv2 PNG), ``uint8 [H, W]`` or
    ``uint16 [H, W]`` (16-bit PNG, e.g. TUM depth), atomically."""
    if image.ndim == 3:
        image = np.ascontiguousarray(image[..., ::-1])
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise OSError(f"could not encode {path}")
    return write_bytes(path, buf.tobytes())


def write_manifest(
    folder: Path, command: str, entries: Iterable[str] | None = None, announced: Iterable[str] = ()
) -> None:
    """Record ``entries`` (default: everything now in ``folder``) as slimseg's, each with what
    is there now (kind, size, SHA-256: :mod:`slimseg.utils.manifest`), atomically. A name in
    ``announced`` that does not exist yet is listed as to be written (``null``)."""
    announced = set(announced)
    names = [p.name for p in folder.iterdir()] if entries is None else list(entries)
    names += sorted(announced - set(names))
    write_text(folder / MANIFEST, manifest_text(command, record_entries(folder, names, announced)))


def add_to_manifest(folder: Path, command: str, entries: Iterable[str]) -> None:
    """List ``entries`` in ``folder``'s manifest as announced (``null``: a folder written to
    as a command goes, like a resumable sweep, whose entries change between runs); earlier
    entries keep their records."""
    names = set(entries)
    kept = {n: r for n, r in (read_entries(folder) or {}).items() if n not in names}
    body = kept | dict.fromkeys(n for n in names if confined_name(n))
    write_text(folder / MANIFEST, manifest_text(command, body))
