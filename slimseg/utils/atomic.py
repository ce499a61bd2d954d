"""Atomic file writes: every output goes to a temporary name in its folder, then ``os.replace``.

A reader never sees a half-written file, and an interrupted write leaves the previous version
(or nothing) in place. ``atomic_path`` serves writers that take a path (``torch.save``,
``Figure.savefig``, ``cv2.imwrite``); the ``write_*`` helpers cover the common formats.
"""

from __future__ import annotations

import json
import os
import secrets
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import yaml


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix, so format sniffing works); on a
    clean exit it replaces ``path``, on an exception it is removed. Creates the folder.

    The temporary name holds the host, the process id and a random token, so writers on
    several machines sharing one folder (NFS, a sweep across a cluster) never share it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tag = f"{socket.gethostname()}.{os.getpid()}.{secrets.token_hex(4)}"
    tmp = path.with_name(f".{path.stem}.{tag}.tmp{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


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
