"""The letterbox rule: the one place that defines how frames are fitted to the network input.

Training, validation, export metadata and every predictor use these functions, so a C++
runtime that follows the same four lines gets pixel-exact masks:

1. ``scale = min(H_in / h, W_in / w)`` (also upscales small frames);
2. ``new_w = floor(w · scale + 0.5)``, ``new_h = floor(h · scale + 0.5)`` (round half up);
3. resize with bilinear interpolation (``cv2.INTER_LINEAR``);
4. pad centred: ``left = (W_in − new_w) // 2``, ``top = (H_in − new_h) // 2`` (the odd pixel
   goes right/bottom), pad value 114 on all three channels.

Inverse: ``x_frame = (x_input − left) / scale`` (same for y with ``top``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from slimseg.errors import SlimsegError

PAD_VALUE = 114


@dataclass(frozen=True)
class LetterboxParams:
    """Geometry of one letterbox: source ``(h, w)`` → network input ``(H_in, W_in)``."""

    scale: float
    new_w: int
    new_h: int
    left: int
    top: int
    out_w: int
    out_h: int

    def to_dict(self) -> dict:
        return {
            "scale": self.scale,
            "new_size": [self.new_w, self.new_h],
            "pad_left_top": [self.left, self.top],
        }


def letterbox_params(h: int, w: int, out_h: int, out_w: int | None = None) -> LetterboxParams:
    """Compute the letterbox geometry for a ``h × w`` frame and an ``out_h × out_w`` input."""
    out_w = out_h if out_w is None else out_w
    if h <= 0 or w <= 0:
        raise SlimsegError(f"cannot letterbox an empty frame of {w}x{h} pixels: give an image")
    scale = min(out_h / h, out_w / w)
    new_w = min(out_w, math.floor(w * scale + 0.5))
    new_h = min(out_h, math.floor(h * scale + 0.5))
    if new_w < 1 or new_h < 1:  # a 1 x 5000 frame scaled to 640 would be 0 pixels high
        raise SlimsegError(
            f"a frame of {w}x{h} pixels is too thin to letterbox to {out_w}x{out_h} (it would "
            f"be {new_w}x{new_h}): give a frame whose sides differ less"
        )
    return LetterboxParams(
        scale, new_w, new_h, (out_w - new_w) // 2, (out_h - new_h) // 2, out_w, out_h
    )


def letterbox_image(image: np.ndarray, p: LetterboxParams, pad: int = PAD_VALUE) -> np.ndarray:
    """``[h, w, C]`` (or ``[h, w]``) → ``[H_in, W_in, C]`` resized bilinearly and padded."""
    return _place(image, p, cv2.INTER_LINEAR, pad)


def letterbox_mask(mask: np.ndarray, p: LetterboxParams) -> np.ndarray:
    """``[h, w]`` mask → ``[H_in, W_in]``, nearest pixel centre (INTER_NEAREST_EXACT), padded 0."""
    return _place(mask, p, cv2.INTER_NEAREST_EXACT, 0)


def _place(array: np.ndarray, p: LetterboxParams, interp: int, pad: int) -> np.ndarray:
    h, w = array.shape[:2]
    if (h, w) != (p.new_h, p.new_w):
        array = cv2.resize(array, (p.new_w, p.new_h), interpolation=interp)
    out = np.full((p.out_h, p.out_w, *array.shape[2:]), pad, dtype=array.dtype)
    out[p.top : p.top + p.new_h, p.left : p.left + p.new_w] = array
    return out


def boxes_to_frame(boxes: np.ndarray, p: LetterboxParams, h: int, w: int) -> np.ndarray:
    """xyxy boxes ``[N, 4]`` in network-input pixels → source-frame pixels, clipped."""
    out = boxes.astype(np.float32).copy()
    out[:, [0, 2]] = (out[:, [0, 2]] - p.left) / p.scale
    out[:, [1, 3]] = (out[:, [1, 3]] - p.top) / p.scale
    out[:, [0, 2]] = out[:, [0, 2]].clip(0, w)
    out[:, [1, 3]] = out[:, [1, 3]].clip(0, h)
    return out
