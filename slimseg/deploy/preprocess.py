"""Network input of one frame: the shared letterbox, RGB / 255, NCHW (predict, calibration)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from slimseg.errors import SlimsegError
from slimseg.ops.letterbox import LetterboxParams, letterbox_image, letterbox_params

MAX_STRIDE = 32


def parse_imgsz(imgsz: int | Sequence[int] | None) -> tuple[int, int] | None:
    """``H`` or ``(H, W)`` → ``(H, W)``, both positive multiples of 32 (``None`` passes)."""
    if imgsz is None:
        return None
    if isinstance(imgsz, int):
        hw = (imgsz, imgsz)
    else:
        values = [int(v) for v in imgsz]
        if len(values) not in (1, 2):
            raise SlimsegError(f"imgsz must be H or (H, W), got {list(values)}")
        hw = (values[0], values[-1])
    if min(hw) <= 0 or hw[0] % MAX_STRIDE or hw[1] % MAX_STRIDE:
        raise SlimsegError(f"imgsz {list(hw)} must be positive multiples of {MAX_STRIDE}")
    return hw


def preprocess_frame(
    image_rgb: np.ndarray, imgsz: tuple[int, int], dtype: type = np.float32
) -> tuple[np.ndarray, dict]:
    """``uint8 [h, w, 3]`` RGB → ``[1, 3, H, W]`` input (``dtype``) and its letterbox meta
    (``letterbox``: :class:`LetterboxParams`, ``orig_shape``: ``(h, w)``)."""
    if (
        not isinstance(image_rgb, np.ndarray)
        or image_rgb.dtype != np.uint8
        or image_rgb.ndim != 3
        or image_rgb.shape[2] != 3
    ):
        got = (
            f"{image_rgb.dtype} {image_rgb.shape}"
            if isinstance(image_rgb, np.ndarray)
            else type(image_rgb).__name__
        )
        raise ValueError(f"expected an RGB uint8 image [h, w, 3], got {got}")
    h, w = image_rgb.shape[:2]
    p: LetterboxParams = letterbox_params(h, w, *imgsz)
    boxed = letterbox_image(image_rgb, p)
    # Division (not a multiply by 1/255): bit-identical to the training collate.
    x = boxed.transpose(2, 0, 1)[None].astype(np.float32) / np.float32(255)
    return np.ascontiguousarray(x, dtype=dtype), {"letterbox": p, "orig_shape": (h, w)}
