"""Raw dumps: one frame's network input and outputs, as onnxruntime gave them, in one file.

What ``slimseg predict --dump-raw DIR`` writes per frame (``DIR/<stem>.ssraw``) so that a C++
runtime (``export/cpp``, docs/cpp_consumer.md) can be checked against slimseg on the very same
tensors. The format is named tensors, every number little-endian:

- 8 bytes ``SLSGRAW1``, ``uint32`` tensor count;
- per tensor: ``uint32`` name length, the name (UTF-8), ``uint32`` dtype (0 float32,
  1 float16, 2 int32, 3 uint8), ``uint32`` ndim, ``int64`` dims, the data in C order.

Tensors of a dump: ``images [1, 3, H, W]`` (the letterboxed input), ``output0`` (+ ``output1``)
or ``logits`` (export/CONTRACT.md), ``frame_hw`` int32 ``[2]`` and ``keypoints`` float32
``[N, 2]`` (x, y frame pixels: the ORB keypoints ``slimseg dynamic`` would use), with their
``descriptors`` uint8 ``[N, 32]`` and the frame's FAST ``corners`` float32 ``[P, 2]`` (the
degrading rule's static support) as the chain computed them; with ``--dump-depth``
``depth_m`` float32 ``[H, W]`` and the camera's ``camera`` float32 ``[4]`` (fx, fy, cx, cy):
what the C++ chain's multi-frame stages need (docs/cpp_consumer.md).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from slimseg.errors import SlimsegError
from slimseg.utils.atomic import atomic_path

MAGIC = b"SLSGRAW1"
SUFFIX = ".ssraw"
DTYPES = (np.float32, np.float16, np.int32, np.uint8)  # code = index
MAX_NDIM = 8


def write_raw(path: str | Path, tensors: dict[str, np.ndarray]) -> Path:
    """Write ``tensors`` (float32, float16, int32 or uint8 arrays) to ``path`` atomically."""
    parts = [MAGIC, struct.pack("<I", len(tensors))]
    for name, value in tensors.items():
        a = np.ascontiguousarray(value)
        codes = [i for i, d in enumerate(DTYPES) if a.dtype == d]
        if not codes:
            raise ValueError(f"raw dump tensor {name}: dtype {a.dtype} is not one of {DTYPES}")
        encoded = name.encode()
        parts += [struct.pack("<I", len(encoded)), encoded, struct.pack("<II", codes[0], a.ndim)]
        parts += [struct.pack("<q", d) for d in a.shape]
        parts.append(a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes())
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(b"".join(parts))
    return path


def read_raw(path: str | Path) -> dict[str, np.ndarray]:
    """The tensors of a raw dump (also the C++ example's ``.ssres`` results), by name.
    :class:`SlimsegError` naming the file on anything malformed."""
    path = Path(path)
    data = path.read_bytes()
    pos = 0

    def take(n: int, what: str) -> bytes:
        nonlocal pos
        if pos + n > len(data):
            raise SlimsegError(f"{path}: truncated raw dump (reading {what} at byte {pos})")
        pos += n
        return data[pos - n : pos]

    if take(8, "the magic") != MAGIC:
        raise SlimsegError(f"{path}: not a slimseg raw dump (no {MAGIC.decode()} header)")
    (count,) = struct.unpack("<I", take(4, "the tensor count"))
    out: dict[str, np.ndarray] = {}
    for _ in range(count):
        (length,) = struct.unpack("<I", take(4, "a name length"))
        name = take(length, "a name").decode()
        code, ndim = struct.unpack("<II", take(8, f"{name}'s dtype"))
        if code >= len(DTYPES) or ndim > MAX_NDIM:
            raise SlimsegError(f"{path}: tensor {name} has dtype code {code}, ndim {ndim}")
        shape = struct.unpack(f"<{ndim}q", take(8 * ndim, f"{name}'s shape"))
        dtype = np.dtype(DTYPES[code]).newbyteorder("<")
        size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        out[name] = np.frombuffer(take(size, name), dtype).reshape(shape).astype(DTYPES[code])
    if pos != len(data):
        raise SlimsegError(f"{path}: {len(data) - pos} trailing bytes after the last tensor")
    return out


def frame_dump(
    raw: dict[str, np.ndarray],
    frame_hw: tuple[int, int],
    keypoints: np.ndarray,
    depth_m: np.ndarray | None = None,
    *,
    descriptors: np.ndarray | None = None,
    corners: np.ndarray | None = None,
    camera: tuple[float, float, float, float] | None = None,
) -> dict[str, np.ndarray]:
    """A dump's tensors: ``raw`` (``Predictor.predict(..., raw=raw)``: input and outputs), the
    frame size, ``keypoints float32 [N, 2]`` and, optionally, ``depth_m float32 [H, W]``
    (metres; the masking rules' depth cut), the keypoints' ORB ``descriptors uint8 [N, 32]``,
    the FAST ``corners float32 [P, 2]`` and the ``camera`` ``(fx, fy, cx, cy)`` px."""
    kps = np.asarray(keypoints, np.float32).reshape(-1, 2)
    out = {**raw, "frame_hw": np.asarray(frame_hw, np.int32), "keypoints": kps}
    if descriptors is not None:
        desc = np.asarray(descriptors, np.uint8)
        if desc.shape != (len(kps), 32):
            raise ValueError(f"descriptors {list(desc.shape)}: expected [{len(kps)}, 32]")
        out["descriptors"] = np.ascontiguousarray(desc)
    if corners is not None:
        out["corners"] = np.asarray(corners, np.float32).reshape(-1, 2)
    if depth_m is not None:
        out["depth_m"] = np.ascontiguousarray(depth_m, np.float32)
    if camera is not None:
        out["camera"] = np.asarray(camera, np.float32).reshape(4)
    return out
