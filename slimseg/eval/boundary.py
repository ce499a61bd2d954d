"""Inner boundary bands of binary masks (Boundary IoU, Cheng et al., CVPR 2021).

The band of width ``d`` of a mask ``M`` is ``M`` minus its erosion by a ``(2d + 1) × (2d + 1)``
square (``d`` passes of a 3 × 3 erosion), pixels outside the image counting as background:
the mask pixels with a background pixel, or the image edge, within Chebyshev distance ``d``.
Boundary IoU of two masks is the IoU of their bands; it is 1 for identical masks and, unlike
mask IoU, falls as fast for a large object as for a small one when its edge is misplaced.
See docs/mask_quality.md for the definitions and the band sizes.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import cv2
import numpy as np
from pycocotools import mask as mask_utils

#: ``d = max(1, round(DILATION_RATIO × image diagonal))``: Boundary IoU's default band.
DILATION_RATIO = 0.02
#: Narrow band widths in pixels reported besides the default band (thin limbs at 320 px).
NARROW_BANDS = (1, 2)


def band_width(image_hw: tuple[int, int], dilation_ratio: float = DILATION_RATIO) -> int:
    """The default band width in pixels of an ``(h, w)`` image: ``max(1, round(ratio ×
    sqrt(h² + w²)))`` (e.g. 9 px for 320 × 320, 16 px for 640 × 480)."""
    h, w = image_hw
    if dilation_ratio <= 0:
        raise ValueError(f"dilation_ratio must be > 0, got {dilation_ratio}")
    return max(1, round(dilation_ratio * math.hypot(h, w)))


def _windows_band(stack: np.ndarray, boxes: np.ndarray, d: int) -> np.ndarray:
    """The band of width ``d`` of every mask of ``uint8 [N, A, B]`` whose nonzero pixels lie
    in the window ``boxes [N, 4]`` (int ``a0, b0, a1, b1``, end exclusive); same shape.

    Each window is eroded on its own with a constant 0 border: the mask is 0 outside its
    window (and outside the image), so this is the erosion of the whole mask."""
    kernel = np.ones((2 * d + 1, 2 * d + 1), np.uint8)
    out = np.zeros(stack.shape, np.uint8)
    for k, (a0, b0, a1, b1) in enumerate(boxes.tolist()):
        if a1 <= a0 or b1 <= b0:
            continue
        win = stack[k, a0:a1, b0:b1]
        eroded = cv2.erode(win, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
        out[k, a0:a1, b0:b1] = win & ~eroded
    return out


def _dense_boxes(masks: np.ndarray) -> np.ndarray:
    """``int64 [N, 4]`` ``r0, c0, r1, c1`` (end exclusive) of ``[N, H, W]`` masks; empty
    masks give an empty window."""
    rows, cols = masks.any(2), masks.any(1)
    out = np.zeros((len(masks), 4), np.int64)
    for k in range(len(masks)):
        r, c = np.flatnonzero(rows[k]), np.flatnonzero(cols[k])
        if r.size:
            out[k] = (r[0], c[0], r[-1] + 1, c[-1] + 1)
    return out


def boundary_band(masks: np.ndarray, d: int) -> np.ndarray:
    """``bool [N, H, W]`` → ``bool [N, H, W]``: each mask minus its erosion by a
    ``(2d + 1)²`` square (``d >= 1``; outside the image = background); e.g. a 10 × 10
    square gives its 36-pixel outer ring for ``d = 1``."""
    if masks.ndim != 3:
        raise ValueError(f"expected masks [N, H, W], got shape {masks.shape}")
    if d < 1:
        raise ValueError(f"band width must be >= 1 pixel, got {d}")
    stack = np.ascontiguousarray(masks, np.uint8)
    return _windows_band(stack, _dense_boxes(stack), d).astype(bool)


class MaskStack:
    """The masks of one image, decoded once from COCO RLEs, and their boundary bands as RLEs.

    Held as pycocotools decodes them: column-major, i.e. ``uint8 [N, W, H]`` (the masks
    transposed), so decoding and encoding copy nothing. The band rule is symmetric under
    transposition (square kernel, same border rule on every side), so the bands computed on
    the transposed masks are the transposed bands.
    """

    def __init__(self, rles: Sequence[dict], image_hw: tuple[int, int]) -> None:
        h, w = image_hw
        self.image_hw = (h, w)
        self.rles = list(rles)
        if not self.rles:
            self._cols = np.zeros((0, w, h), np.uint8)
            self._boxes = np.zeros((0, 4), np.int64)
            return
        with warnings.catch_warnings():
            # pycocotools' Cython array lacks numpy 2's ``copy`` keyword: harmless
            warnings.filterwarnings("ignore", "__array__ implementation", DeprecationWarning)
            fortran = mask_utils.decode(self.rles)  # [H, W, N], Fortran order
        if fortran.shape[:2] != (h, w):
            raise ValueError(f"RLE size {list(fortran.shape[:2])} is not the image's {[h, w]}")
        self._cols = fortran.T  # [N, W, H], C order: the same buffer
        x, y, bw, bh = np.round(mask_utils.toBbox(self.rles)).astype(np.int64).reshape(-1, 4).T
        self._boxes = np.stack([x, y, x + bw, y + bh], axis=1)  # column, then row windows

    def __len__(self) -> int:
        return len(self.rles)

    def mask(self, k: int) -> np.ndarray:
        """``bool [H, W]``: mask ``k`` (a view)."""
        return self._cols[k].T.view(bool)

    def band_rles(self, d: int) -> list[dict]:
        """COCO RLEs (``counts`` str) of every mask's boundary band of width ``d``."""
        if d < 1:
            raise ValueError(f"band width must be >= 1 pixel, got {d}")
        if not self.rles:
            return []
        band = _windows_band(self._cols, self._boxes, d)
        rles = mask_utils.encode(band.T)  # [H, W, N] Fortran order: no copy
        for r in rles:
            r["counts"] = r["counts"].decode("ascii")
        return rles


def boundary_iou(a: np.ndarray, b: np.ndarray, d: int) -> float:
    """Boundary IoU of two ``bool [H, W]`` masks with band width ``d``:
    ``|A_d ∩ B_d| / |A_d ∪ B_d|`` (1.0 when both bands are empty)."""
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(f"expected two [H, W] masks of one shape, got {a.shape} and {b.shape}")
    band = boundary_band(np.stack([a, b]), d)
    union = int((band[0] | band[1]).sum())
    return 1.0 if union == 0 else int((band[0] & band[1]).sum()) / union
