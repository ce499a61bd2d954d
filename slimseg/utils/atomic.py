"""Atomic outputs: every file goes to a temporary name in its folder, then ``os.replace``;
every folder output is built in a temporary folder beside it, then moved into place.

A reader never sees a half-written file, and an interrupted write leaves the previous version
(or nothing) in place. ``atomic_path`` serves writers that take a path (``torch.save``,
``Figure.savefig``, ``cv2.imwrite``); the ``write_*`` helpers cover the common formats;
``staged_dir`` serves commands whose output is a folder (``slimseg dynamic``'s ``masks/`` and
``frames.csv``, ``predict``'s files, ``slam-eval``'s ``trajectories/``): a command that fails
midway leaves its output folder as it was.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import yaml

from slimseg.errors import SlimsegError


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
    path: str | Path, option: str = "--out", owned: tuple[str, ...] = ()
) -> Iterator[Path]:
    """A folder output that appears complete or not at all.

    Yields a fresh temporary folder beside ``path`` (``.NAME.<host.pid.token>.tmp``); the
    caller writes everything there. On a clean exit each top-level entry moves into ``path``
    (created), replacing the entry of the same name whole (a ``masks/`` folder of an earlier
    run is swapped, not merged, so no stale file stays). Entries of ``path`` the command did
    not write are left alone, except those named in ``owned`` (a command's own subfolders),
    which are deleted so an earlier run's never mix with this one's. On an exception the
    temporary folder (and any parent folder this call created) is removed and ``path`` is as
    before. ``SlimsegError`` naming ``option`` when ``path`` exists and is not a folder."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise SlimsegError(f"{option} {path} is a file, not a folder: give a folder path")
    created = [p for p in (path.parent, *path.parent.parents) if not p.exists()]
    path.parent.mkdir(parents=True, exist_ok=True)
    stage = path.with_name(f".{path.name}.{_tag()}.tmp")
    try:
        stage.mkdir()
        yield stage
        entries = sorted(stage.iterdir())
        if entries:  # a run that wrote nothing leaves no folder behind
            path.mkdir(exist_ok=True)
        for entry in entries:
            _move_replacing(entry, path / entry.name)
        for name in set(owned) - {e.name for e in entries}:
            if (path / name).is_dir():
                shutil.rmtree(path / name)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        for p in created:  # innermost first; only folders this call made and left empty
            if p.is_dir() and not path.exists() and not any(p.iterdir()):
                p.rmdir()


def _move_replacing(src: Path, dst: Path) -> None:
    """Rename ``src`` to ``dst``; an existing folder at ``dst`` (or anything where a folder
    goes) is moved aside first and deleted once ``src`` is in place."""
    if not os.path.lexists(dst) or not (dst.is_dir() or src.is_dir()):
        os.replace(src, dst)
        return
    old = dst.with_name(f".{dst.name}.{_tag()}.old")
    os.replace(dst, old)
    os.replace(src, dst)
    if old.is_dir() and not old.is_symlink():
        shutil.rmtree(old)
    else:
        old.unlink()


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
