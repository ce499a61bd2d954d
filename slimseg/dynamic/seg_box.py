"""Eq. 4 of the substation paper: per detection, its seg mask or its filled box; box masks and
mask dilation (docs/papers.md §2).

The paper calls this detection/segmentation "fusion" (the ``fusion`` mode keeps that name); it
is unrelated to fusing a network's BatchNorm layers (``slimseg.layers.fuse``).
"""

from __future__ import annotations

import cv2
import numpy as np

T_O = 0.25  # Eq. 4: keep the seg mask when it covers more than this fraction of its box


def box_masks(boxes: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """Filled boxes ``[M, 4]`` xyxy px → ``bool [M, H, W]`` (pixel centres inside the box)."""
    h, w = hw
    xs, ys = np.arange(w) + 0.5, np.arange(h) + 0.5
    in_x = (xs[None] >= boxes[:, 0:1]) & (xs[None] < boxes[:, 2:3])
    in_y = (ys[None] >= boxes[:, 1:2]) & (ys[None] < boxes[:, 3:4])
    return in_y[:, :, None] & in_x[:, None, :]


def fuse_seg_box(
    seg_masks: np.ndarray, boxes: np.ndarray, t_o: float = T_O
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 4: ``s_o = area(seg ∩ box) / area(box)``; seg mask if ``s_o > t_o``, else the box.

    ``seg_masks bool [M, H, W]``, ``boxes [M, 4]`` → ``(fused bool [M, H, W], used_seg [M])``.
    """
    boxes_m = box_masks(boxes, seg_masks.shape[1:])
    box_area = boxes_m.sum((1, 2)).clip(min=1)
    s_o = (seg_masks & boxes_m).sum((1, 2)) / box_area
    used_seg = s_o > t_o
    return np.where(used_seg[:, None, None], seg_masks, boxes_m), used_seg


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Dilate a ``[H, W]`` mask by ``radius`` px with a disc (0: unchanged)."""
    if radius <= 0:
        return mask
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    return cv2.dilate(mask.astype(np.uint8), kernel).astype(mask.dtype)
