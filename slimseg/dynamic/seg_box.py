"""Eq. 4 of the substation paper: per detection, its seg mask or its filled box; box masks and
mask dilation (docs/papers.md §2).

The paper calls this detection/segmentation "fusion" (the ``fusion`` mode keeps that name); it
is unrelated to fusing a network's BatchNorm layers (``slimseg.layers.fuse``).
"""

from __future__ import annotations

import cv2
import numpy as np

from slimseg.dynamic.knobs import papers

T_O = papers("t_o")  # Eq. 4: keep the seg mask when it covers more than this fraction of its box


def box_masks(boxes: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """Filled boxes ``[M, 4]`` xyxy px → ``bool [M, H, W]`` (pixel centres inside the box)."""
    h, w = hw
    xs, ys = np.arange(w) + 0.5, np.arange(h) + 0.5
    in_x = (xs[None] >= boxes[:, 0:1]) & (xs[None] < boxes[:, 2:3])
    in_y = (ys[None] >= boxes[:, 1:2]) & (ys[None] < boxes[:, 3:4])
    return in_y[:, :, None] & in_x[:, None, :]


def box_spans(boxes: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """``int [M, 4]`` rows ``y0, y1, x0, x1``: the pixel ranges whose centres lie inside each
    box ``[M, 4]`` xyxy (the pixels :func:`box_masks` sets), clipped to the ``hw`` frame."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    x0 = np.ceil(b[:, 0] - 0.5).clip(0, hw[1])
    x1 = np.ceil(b[:, 2] - 0.5).clip(0, hw[1])
    y0 = np.ceil(b[:, 1] - 0.5).clip(0, hw[0])
    y1 = np.ceil(b[:, 3] - 0.5).clip(0, hw[0])
    return np.stack([y0, np.maximum(y1, y0), x0, np.maximum(x1, x0)], 1).astype(np.int64)


def fuse_seg_box(
    seg_masks: np.ndarray, boxes: np.ndarray, t_o: float | np.ndarray = T_O
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 4: ``s_o = area(seg ∩ box) / area(box)``; seg mask if ``s_o > t_o``, else the box.

    ``seg_masks bool [M, H, W]``, ``boxes [M, 4]``, ``t_o`` one for all or ``[M]`` →
    ``(fused bool [M, H, W], used_seg [M])``. Each box's pixels are counted on its own span
    (the cost of the boxes, not of M frames).
    """
    spans = box_spans(boxes, seg_masks.shape[1:])
    fused = seg_masks.copy()
    used_seg = np.zeros(len(spans), bool)
    t_o = np.broadcast_to(np.asarray(t_o, np.float64), (len(spans),))
    for k, (y0, y1, x0, x1) in enumerate(spans):
        box_area = max((y1 - y0) * (x1 - x0), 1)
        used_seg[k] = int(seg_masks[k, y0:y1, x0:x1].sum()) / box_area > t_o[k]
        if not used_seg[k]:
            fused[k] = False
            fused[k, y0:y1, x0:x1] = True
    return fused, used_seg


def box_keypoint_mobility(
    keypoints: np.ndarray, boxes: np.ndarray, hw: tuple[int, int], mobility: np.ndarray
) -> np.ndarray:
    """``keypoint_mobility(keypoints, box_masks(boxes, hw), mobility)`` without the masks:
    the highest prior of the boxes containing each keypoint (rounded and clipped as there)
    → ``float32 [N]``."""
    n = len(keypoints)
    if n == 0 or len(boxes) == 0:
        return np.zeros(n, np.float32)
    h, w = hw
    x = np.clip(np.round(keypoints[:, 0]).astype(int), 0, w - 1)
    y = np.clip(np.round(keypoints[:, 1]).astype(int), 0, h - 1)
    sp = box_spans(boxes, hw)
    inside = ((y[None] >= sp[:, :1]) & (y[None] < sp[:, 1:2]) & (x[None] >= sp[:, 2:3])
              & (x[None] < sp[:, 3:4]))  # fmt: skip
    return np.where(inside, np.asarray(mobility, np.float32)[:, None], 0.0).max(0)


def dilate_masks(masks: np.ndarray, radius: int) -> np.ndarray:
    """:func:`dilate` of each of ``masks bool [M, H, W]``, computed on the crop around its
    set pixels (the same pixels: nothing outside a mask's bounds grows) → ``bool [M, H, W]``."""
    if radius <= 0 or len(masks) == 0:
        return masks
    h, w = masks.shape[1:]
    radius = min(radius, h + w)  # a disc that wide already covers the image: same result
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    out = np.zeros(masks.shape, bool)
    for k, m in enumerate(masks):
        rows = np.flatnonzero(m.any(1))
        if not len(rows):
            continue
        cols = np.flatnonzero(m.any(0))
        y0, y1 = max(rows[0] - radius, 0), min(rows[-1] + 1 + radius, h)
        x0, x1 = max(cols[0] - radius, 0), min(cols[-1] + 1 + radius, w)
        crop = np.ascontiguousarray(m[y0:y1, x0:x1]).view(np.uint8)
        out[k, y0:y1, x0:x1] = cv2.dilate(crop, kernel).view(bool)
    return out


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Dilate a ``[H, W]`` mask by ``radius`` px with a disc (0: unchanged)."""
    if radius <= 0:
        return mask
    radius = min(radius, sum(mask.shape[:2]))  # wider covers the image all the same: bounded
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    return cv2.dilate(mask.astype(np.uint8), kernel).astype(mask.dtype)
