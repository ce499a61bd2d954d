"""The one image reader: image and depth files → arrays, with errors that name the file.

Images are decoded from the file's bytes (``np.fromfile`` + ``cv2.imdecode``, so any path
works), as stored (``cv2.IMREAD_UNCHANGED``; EXIF orientation is *not* applied: COCO
annotations refer to the stored pixel grid), then converted to ``uint8 [H, W, 3]`` RGB:
grayscale replicated, alpha dropped (no compositing), 16-bit mapped by ``round(v / 257)``.
Depth maps are TUM's ``uint16`` (5000 = 1 m).

Before anything is decoded, the size the file's header declares is checked against a pixel
cap (:data:`DEFAULT_MAX_PIXELS`, or the ``SLIMSEG_MAX_IMAGE_PIXELS`` environment variable): a
661-byte PNG may declare 50000 x 50000 pixels, which would take gigabytes to decode.
"""

from __future__ import annotations

import io
import os
import stat
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from slimseg.data.problems import ImageProblem
from slimseg.errors import SlimsegError

MAX_PIXELS_ENV = "SLIMSEG_MAX_IMAGE_PIXELS"
DEFAULT_MAX_PIXELS = 100_000_000  # 100 MP: 10000 x 10000; a TUM frame is 0.3 MP


def max_image_pixels() -> int:
    """The pixel cap: ``SLIMSEG_MAX_IMAGE_PIXELS`` (a whole number >= 1) or 100 MP."""
    text = os.environ.get(MAX_PIXELS_ENV, "").strip()
    if not text:
        return DEFAULT_MAX_PIXELS
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise SlimsegError(f"{MAX_PIXELS_ENV}={text!r}: give a whole number of pixels >= 1")
    return value


def check_declared_size(path: Path | str, buf: np.ndarray) -> None:
    """:class:`ImageProblem` (``unreadable_image``) naming ``path`` and the size its header
    declares when that is over :func:`max_image_pixels`. Only the header is parsed (Pillow's
    lazy open); formats Pillow does not know are left to the decoder."""
    cap = max_image_pixels()
    size = _header_size(buf)
    if size is None:
        return  # not a format Pillow parses (or a broken header): the decoder decides
    w, h = size
    if w * h > cap:
        raise ImageProblem(
            "unreadable_image",
            f"{path}: declares {w}x{h} pixels ({w * h / 1e6:.1f} MP), over the {cap / 1e6:g} MP "
            f"cap (raise it with {MAX_PIXELS_ENV}=N if the image is genuine)",
        )


def _header_size(buf: np.ndarray) -> tuple[int, int] | None:
    """``(W, H)`` from the header alone: Pillow's format parsers, called directly (no pixel is
    decoded, and no process-wide warning filter or limit is touched: ``Image.open`` would
    warn or refuse on its own limits, which are not this cap)."""
    head = buf[:16].tobytes()
    for load in (Image.preinit, Image.init):  # the common formats first, then every plugin
        load()
        for fmt in Image.ID:
            factory, accept = Image.OPEN[fmt]
            if accept is not None and not accept(head):
                continue
            try:
                return factory(io.BytesIO(buf), None).size
            except (OSError, ValueError, SyntaxError, TypeError, IndexError, EOFError):
                continue
    return None


def decode_file(path: Path, flags: int) -> np.ndarray | None:
    """``cv2.imdecode`` of the file's bytes with ``flags``; None if unreadable, empty or not a
    regular file (a FIFO, a device).
    A header over the pixel cap raises :class:`ImageProblem` (:func:`check_declared_size`)."""
    path = Path(path)
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):  # a FIFO or a device: never read
            return None
        buf = np.fromfile(path, dtype=np.uint8)
    except OSError:
        return None
    if buf.size == 0:
        return None
    return decode_bytes(buf, flags, path)


def decode_bytes(buf: np.ndarray, flags: int, source: Path | str) -> np.ndarray | None:
    """``cv2.imdecode`` of an encoded image's bytes ``uint8 [B]`` (a file's, a bag message's)
    with ``flags``; None if it does not decode. A header over the pixel cap raises
    :class:`ImageProblem` naming ``source`` (:func:`check_declared_size`)."""
    check_declared_size(source, buf)
    return cv2.imdecode(buf, flags)


def _read_unchanged(path: Path, what: str, missing: str, unreadable: str) -> np.ndarray:
    """Decode ``path`` as stored (any depth/channels); ImageProblem of kind ``missing`` or
    ``unreadable`` with the same messages for images and depth maps."""
    if not path.is_file():
        raise ImageProblem(missing, f"{path}: {what} file not found")
    array = decode_file(path, cv2.IMREAD_UNCHANGED)
    if array is None:
        raise ImageProblem(unreadable, f"{path}: corrupt or unreadable {what} file")
    return array


def read_image_rgb8(path: str | Path) -> tuple[np.ndarray, list[str]]:
    """Read an image file as ``uint8 [H, W, 3]`` RGB.

    Returns the image and the conversion kinds applied (``grayscale_image``, ``rgba_image``,
    ``16bit_image``). Raises :class:`ImageProblem` (``missing_image`` / ``unreadable_image``).
    """
    path = Path(path)
    img = _read_unchanged(path, "image", "missing_image", "unreadable_image")
    notes: list[str] = []
    if img.dtype == np.uint16:
        img = np.round(img.astype(np.float32) / 257.0).astype(np.uint8)
        notes.append("16bit_image")
    elif img.dtype != np.uint8:
        raise ImageProblem(
            "unreadable_image", f"{path}: unsupported pixel type {img.dtype} (need 8/16-bit)"
        )
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] == 2:  # gray + alpha
        img = img[:, :, 0]
        notes.append("rgba_image")
    if img.ndim == 2:
        notes.append("grayscale_image")
        return np.ascontiguousarray(np.repeat(img[:, :, None], 3, axis=2)), notes
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ImageProblem("unreadable_image", f"{path}: unsupported image shape {img.shape}")
    if img.shape[2] == 4:
        notes.append("rgba_image")
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB), notes
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB), notes  # a plain channel swap, SIMD


def read_depth(path: str | Path, height: int, width: int) -> np.ndarray:
    """Read a depth map as ``uint16 [H, W]``; raises :class:`ImageProblem` on any mismatch."""
    path = Path(path)
    depth = _read_unchanged(path, "depth", "missing_depth", "bad_depth")
    if depth.dtype != np.uint16 or depth.ndim != 2 or depth.shape != (height, width):
        raise ImageProblem(
            "bad_depth",
            f"{path}: depth must be 16-bit single-channel {width}x{height}, got {depth.dtype} "
            f"{depth.shape}",
        )
    return depth


def depth_path_for(depth_dir: Path, file_name: str) -> Path:
    """The depth file of an image: same relative path, ``.png`` suffix, under ``depth_dir``."""
    return depth_dir / Path(file_name).with_suffix(".png")


def read_rgb(path: str | Path) -> np.ndarray:
    """An image file as ``uint8 [H, W, 3]`` RGB (conversions as :func:`read_image_rgb8`)."""
    return read_image_rgb8(path)[0]
