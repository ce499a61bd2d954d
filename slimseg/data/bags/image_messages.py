"""ROS image messages → arrays: colour as ``uint8 [H, W, 3]`` RGB, depth as ``float32 [H, W]``
metres with 0 where there is no depth (what a :class:`~slimseg.data.frame_source.FrameSource`
loads).

``sensor_msgs/Image``: colour in :data:`COLOUR_ENCODINGS`, depth in :data:`DEPTH_ENCODINGS`
(``16UC1`` / ``mono16``: millimetres; ``32FC1``: metres, NaN or inf = no depth); rows may be
padded (``step``) and big-endian. ``sensor_msgs/CompressedImage``: JPEG / PNG colour, and the
``compressed_depth_image_transport`` layout (``format`` holding ``compressedDepth``: a 12-byte
header - int32 format, float32 quantisation a, b - then a 16-bit PNG; ``16UC1`` millimetres,
``32FC1`` inverse depth ``a / (v - b)``). Anything else is a ``ValueError`` whose message the
sequence reader puts in its one-line error.
"""

from __future__ import annotations

import struct

import cv2
import numpy as np

from slimseg.data.images import decode_bytes
from slimseg.data.tum import depth_metres

MM_PER_M = 1000.0
COLOUR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8", "mono8")
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")
_COLOUR_CHANNELS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}
_TO_RGB = {
    "bgr8": cv2.COLOR_BGR2RGB,
    "rgba8": cv2.COLOR_RGBA2RGB,
    "bgra8": cv2.COLOR_BGRA2RGB,
    "mono8": cv2.COLOR_GRAY2RGB,
}
COMPRESSED_DEPTH_HEADER = 12  # bytes before the PNG: int32 format, float32 a, float32 b


def _rows(msg: object, dtype: np.dtype, channels: int) -> np.ndarray:
    """``msg.data`` as ``[H, W, C]`` (or ``[H, W]``) of ``dtype``, honouring ``step``."""
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    row = w * channels * dt.itemsize
    data = np.asarray(msg.data, np.uint8)
    if h == 0 or w == 0:
        raise ValueError(f"empty image {w}x{h}")
    if step < row or data.size < step * (h - 1) + row:
        raise ValueError(
            f"{w}x{h} {msg.encoding} needs {row} bytes per row, step {step}, {data.size} bytes"
        )
    rows = np.lib.stride_tricks.as_strided(data, (h, row), (step, 1))
    arr = np.ascontiguousarray(rows).view(dt).reshape(h, w, channels)
    arr = arr.astype(dt.newbyteorder("="), copy=False)
    return arr[:, :, 0] if channels == 1 else arr


def colour_from_image(msg: object) -> np.ndarray:
    """``sensor_msgs/Image`` → ``uint8 [H, W, 3]`` RGB."""
    enc = str(msg.encoding)
    if enc not in _COLOUR_CHANNELS:
        raise ValueError(f"colour encoding {enc!r} is not one of {', '.join(COLOUR_ENCODINGS)}")
    arr = _rows(msg, np.uint8, _COLOUR_CHANNELS[enc])
    return np.ascontiguousarray(arr) if enc == "rgb8" else cv2.cvtColor(arr, _TO_RGB[enc])


def depth_from_image(msg: object) -> np.ndarray:
    """``sensor_msgs/Image`` depth → ``float32 [H, W]`` metres, 0 = no depth."""
    enc = str(msg.encoding)
    if enc in ("16UC1", "mono16"):
        return depth_metres(_rows(msg, np.uint16, 1), MM_PER_M)
    if enc == "32FC1":
        return _clean(_rows(msg, np.float32, 1).copy())
    raise ValueError(f"depth encoding {enc!r} is not one of {', '.join(DEPTH_ENCODINGS)}")


def colour_from_compressed(msg: object) -> np.ndarray:
    """``sensor_msgs/CompressedImage`` (JPEG/PNG) → ``uint8 [H, W, 3]`` RGB."""
    fmt = str(msg.format)
    if "compresseddepth" in fmt.lower():
        raise ValueError(f"format {fmt!r} is compressed depth, not colour")
    bgr = decode_bytes(np.asarray(msg.data, np.uint8), cv2.IMREAD_COLOR, f"{fmt} message")
    if bgr is None:
        raise ValueError(f"compressed image (format {fmt!r}) does not decode as JPEG or PNG")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def depth_from_compressed(msg: object) -> np.ndarray:
    """``sensor_msgs/CompressedImage`` depth (``compressedDepth`` PNG, or a plain 16-bit PNG in
    millimetres) → ``float32 [H, W]`` metres, 0 = no depth."""
    fmt = str(msg.format)
    data = np.asarray(msg.data, np.uint8)
    kind = fmt.split(";")[0].strip()
    if "compresseddepth" in fmt.lower():
        if "rvl" in fmt.lower():
            raise ValueError(f"compressedDepth format {fmt!r}: only PNG is supported, not RVL")
        if data.size <= COMPRESSED_DEPTH_HEADER:
            raise ValueError(f"compressedDepth message of {data.size} bytes has no image")
        _, qa, qb = struct.unpack_from("<iff", data.tobytes()[:COMPRESSED_DEPTH_HEADER])
        raw = decode_bytes(data[COMPRESSED_DEPTH_HEADER:], cv2.IMREAD_UNCHANGED, f"{fmt} message")
        if raw is None or raw.dtype != np.uint16 or raw.ndim != 2:
            raise ValueError(f"compressedDepth ({fmt!r}) does not hold a 16-bit PNG")
        if kind == "32FC1":  # quantised inverse depth
            v = raw.astype(np.float32)
            with np.errstate(divide="ignore", invalid="ignore"):
                depth = np.where(raw > 0, np.float32(qa) / (v - np.float32(qb)), 0)
            return _clean(depth.astype(np.float32))
        if kind in ("16UC1", "mono16", ""):
            return depth_metres(raw, MM_PER_M)
        raise ValueError(f"compressedDepth of {kind!r}: expected 16UC1 or 32FC1")
    raw = decode_bytes(data, cv2.IMREAD_UNCHANGED, f"{fmt} message")
    if raw is None or raw.dtype != np.uint16 or raw.ndim != 2:
        raise ValueError(
            f"compressed depth (format {fmt!r}) is not a 16-bit single-channel PNG; "
            "expected compressedDepth or a 16UC1 PNG"
        )
    return depth_metres(raw, MM_PER_M)


def _clean(depth: np.ndarray) -> np.ndarray:
    """Zero where depth is NaN, infinite or negative (no depth), in place."""
    depth[~np.isfinite(depth) | (depth < 0)] = 0.0
    return depth
