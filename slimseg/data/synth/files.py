"""Atomic file writes: every output goes to a temporary name in its folder, then ``os.replace``.

A reader therefore never sees a half-written PNG or json, even if generation is interrupted.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import yaml


def write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text(path: Path, text: str) -> None:
    """UTF-8 text, atomically."""
    write_bytes(path, text.encode("utf-8"))


def write_png(path: Path, image: np.ndarray) -> None:
    """``uint8 [H, W, 3]`` RGB (stored as BGR, like every cv2 PNG), ``uint8 [H, W]`` or
    ``uint16 [H, W]`` (16-bit PNG, e.g. TUM depth)."""
    if image.ndim == 3:
        image = np.ascontiguousarray(image[..., ::-1])
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise OSError(f"could not encode {path}")
    write_bytes(path, buf.tobytes())


def write_json(path: Path, obj: object) -> None:
    """Compact json, atomically."""
    write_text(path, json.dumps(obj, separators=(",", ":")))


def write_yaml(path: Path, obj: object) -> None:
    """YAML (keys in insertion order), atomically."""
    write_text(path, yaml.safe_dump(obj, sort_keys=False, default_flow_style=None))
