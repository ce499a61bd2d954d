"""An object mask stored as its tight crop: what the track stage warps, dilates and compares.

A full ``bool [H, W]`` mask per object and frame costs a 640×480 pass per operation; a person
covers a tenth of that. :class:`Patch` keeps the crop and its top-left corner, and every
operation here (IoU, homography warp, dilation, depth gate, paste) costs the crop's area.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

IOU_FULL_AREA = 1024  # patch_iou counts overlaps below 4x this many pixels in full


@dataclass(frozen=True)
class Patch:
    """``mask bool [h, w]`` whose top-left pixel is frame pixel ``(y0, x0)``."""

    y0: int
    x0: int
    mask: np.ndarray

    @cached_property
    def area(self) -> int:
        """Set pixels (computed once: a patch's mask is never modified in place)."""
        return int(self.mask.sum())

    @property
    def box(self) -> np.ndarray:
        """Tight box of the set pixels, ``[4]`` xyxy px (pixel edges); zeros when empty."""
        rows, cols = np.flatnonzero(self.mask.any(1)), np.flatnonzero(self.mask.any(0))
        if not len(rows):
            return np.zeros(4)
        return np.array(
            [self.x0 + cols[0], self.y0 + rows[0], self.x0 + cols[-1] + 1, self.y0 + rows[-1] + 1],
            np.float64,
        )

    def moved(self, dy: int, dx: int) -> Patch:
        """The same mask ``dy`` rows down and ``dx`` columns right (its area carried over)."""
        out = Patch(self.y0 + dy, self.x0 + dx, self.mask)
        out.__dict__["area"] = self.area  # cached_property's slot: nothing to recount
        return out

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """``bool [N]``: which points ``xy [N, 2]`` (x, y px, rounded) fall on the mask."""
        h, w = self.mask.shape
        x = np.round(np.asarray(xy)[:, 0]).astype(int) - self.x0
        y = np.round(np.asarray(xy)[:, 1]).astype(int) - self.y0
        ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
        out = np.zeros(len(x), bool)
        out[ok] = self.mask[y[ok], x[ok]]
        return out

    def paste(self, hw: tuple[int, int]) -> np.ndarray:
        """The full-frame ``bool [H, W]`` mask (parts outside the frame are cut)."""
        out = np.zeros(hw, bool)
        h, w = self.mask.shape
        y0, x0 = max(self.y0, 0), max(self.x0, 0)
        y1, x1 = min(self.y0 + h, hw[0]), min(self.x0 + w, hw[1])
        if y1 > y0 and x1 > x0:
            out[y0:y1, x0:x1] = self.mask[y0 - self.y0 : y1 - self.y0, x0 - self.x0 : x1 - self.x0]
        return out


def patch_from_mask(mask: np.ndarray, box: np.ndarray | None = None) -> Patch:
    """Crop a full ``bool [H, W]`` mask: inside ``box [4]`` xyxy (a detection's mask is zero
    outside its box, so only that area is read), else the tight crop of its pixels."""
    mask = np.asarray(mask, bool)
    h, w = mask.shape
    if box is not None:
        x0, y0 = max(int(np.floor(box[0])) - 1, 0), max(int(np.floor(box[1])) - 1, 0)
        x1, y1 = min(int(np.ceil(box[2])) + 1, w), min(int(np.ceil(box[3])) + 1, h)
        if x1 > x0 and y1 > y0:
            return Patch(y0, x0, mask[y0:y1, x0:x1].copy())
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    if not len(rows):
        return Patch(0, 0, np.zeros((0, 0), bool))
    y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    return Patch(int(y0), int(x0), mask[y0:y1, x0:x1].copy())


def patch_from_box(box: np.ndarray, hw: tuple[int, int]) -> Patch:
    """A filled box ``[4]`` xyxy as a patch (pixel centres inside the box, clipped)."""
    x0, y0 = max(int(np.ceil(box[0] - 0.5)), 0), max(int(np.ceil(box[1] - 0.5)), 0)
    x1, y1 = min(int(np.ceil(box[2] - 0.5)), hw[1]), min(int(np.ceil(box[3] - 0.5)), hw[0])
    return Patch(y0, x0, np.ones((max(y1 - y0, 0), max(x1 - x0, 0)), bool))


def patch_iou(a: Patch, b: Patch, stride: int = 1) -> float:
    """Intersection over union of two patches (0 when either is empty). ``stride`` k > 1
    counts the intersection on every k-th row and column of the frame (k² times fewer pixels;
    the areas stay exact) where it spans over ``4 ·`` :data:`IOU_FULL_AREA` pixels."""
    ua, ub = a.area, b.area
    if ua == 0 or ub == 0:
        return 0.0
    (ah, aw), (bh, bw) = a.mask.shape, b.mask.shape
    y0, x0 = max(a.y0, b.y0), max(a.x0, b.x0)
    y1, x1 = min(a.y0 + ah, b.y0 + bh), min(a.x0 + aw, b.x0 + bw)
    inter = 0
    if y1 > y0 and x1 > x0:
        k = stride if (y1 - y0) * (x1 - x0) >= 4 * IOU_FULL_AREA else 1
        sa = a.mask[y0 - a.y0 : y1 - a.y0 : k, x0 - a.x0 : x1 - a.x0 : k]
        sb = b.mask[y0 - b.y0 : y1 - b.y0 : k, x0 - b.x0 : x1 - b.x0 : k]
        inter = min(int((sa & sb).sum()) * k * k, ua, ub)
    return inter / float(ua + ub - inter)


def warp_patch(p: Patch, transform: np.ndarray, hw: tuple[int, int]) -> Patch:
    """``p`` moved by ``transform float [3, 3]`` (a homography in frame pixels), nearest
    neighbour, clipped to the ``hw`` frame (empty when it leaves the frame)."""
    h, w = p.mask.shape
    if h == 0 or w == 0:
        return p
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], np.float64) + [p.x0, p.y0]
    moved = cv2.perspectiveTransform(corners.reshape(-1, 1, 2), transform)[:, 0]
    x0, y0 = np.floor(moved.min(0)).astype(int)
    x1, y1 = np.ceil(moved.max(0)).astype(int)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, hw[1]), min(y1, hw[0])
    if x1 <= x0 or y1 <= y0:
        return Patch(0, 0, np.zeros((0, 0), bool))
    src = np.array([[1, 0, p.x0], [0, 1, p.y0], [0, 0, 1]], np.float64)
    dst = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1]], np.float64)
    m = dst @ transform @ src
    out = cv2.warpPerspective(p.mask.view(np.uint8), m, (x1 - x0, y1 - y0),
                              flags=cv2.INTER_NEAREST, borderValue=0)  # fmt: skip
    return Patch(int(y0), int(x0), out > 0)


def clip_patch(p: Patch, hw: tuple[int, int]) -> Patch:
    """``p`` without its rows and columns outside the ``hw`` frame (empty when all are)."""
    h, w = p.mask.shape
    y0, x0 = max(p.y0, 0), max(p.x0, 0)
    y1, x1 = min(p.y0 + h, hw[0]), min(p.x0 + w, hw[1])
    if y0 == p.y0 and x0 == p.x0 and y1 == p.y0 + h and x1 == p.x0 + w:
        return p
    if y1 <= y0 or x1 <= x0:
        return Patch(0, 0, np.zeros((0, 0), bool))
    return Patch(y0, x0, p.mask[y0 - p.y0 : y1 - p.y0, x0 - p.x0 : x1 - p.x0])


def whole_pixel_shift(p: Patch, transform: np.ndarray, tolerance: float) -> tuple[int, int] | None:
    """``(dy, dx)``: the whole-pixel shift that moves ``p`` as ``transform float [3, 3]`` does
    to within ``tolerance`` px at each corner of its crop; None when rotation, scale or
    perspective move some corner further (then :func:`warp_patch` is needed)."""
    h, w = p.mask.shape
    pts = np.array([[0, 0], [w, 0], [0, h], [w, h], [w / 2, h / 2]], np.float64) + [p.x0, p.y0]
    q = pts @ transform[:2, :2].T + transform[:2, 2]
    z = pts @ transform[2, :2] + transform[2, 2]
    d = q / z[:, None] - pts
    dx, dy = round(d[4, 0]), round(d[4, 1])
    if np.abs(d[:4] - [dx, dy]).max() > tolerance:
        return None
    return dy, dx


def dilate_patch(p: Patch, radius: int, hw: tuple[int, int]) -> Patch:
    """``p`` grown by ``radius`` px in every direction (a square element: separable, a third
    of a disc's cost at radius 6), clipped to the ``hw`` frame."""
    if radius <= 0 or p.mask.size == 0:
        return p
    h, w = p.mask.shape
    y0, x0 = max(p.y0 - radius, 0), max(p.x0 - radius, 0)
    y1, x1 = min(p.y0 + h + radius, hw[0]), min(p.x0 + w + radius, hw[1])
    canvas = np.zeros((y1 - y0, x1 - x0), np.uint8)
    sy, sx = p.y0 - y0, p.x0 - x0
    canvas[sy : sy + h, sx : sx + w] = p.mask
    k = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return Patch(int(y0), int(x0), cv2.dilate(canvas, k) > 0)


def patch_depth(p: Patch, depth_m: np.ndarray) -> np.ndarray:
    """The depth (metres) under the patch, ``[h, w]`` (0 outside the frame; a view of
    ``depth_m`` when the patch lies inside it: read only)."""
    h, w = p.mask.shape
    H, W = depth_m.shape
    if p.y0 >= 0 and p.x0 >= 0 and p.y0 + h <= H and p.x0 + w <= W:
        return depth_m[p.y0 : p.y0 + h, p.x0 : p.x0 + w]  # a view: nothing copied
    out = np.zeros((h, w), np.float32)
    y0, x0 = max(p.y0, 0), max(p.x0, 0)
    y1, x1 = min(p.y0 + h, H), min(p.x0 + w, W)
    if y1 > y0 and x1 > x0:
        out[y0 - p.y0 : y1 - p.y0, x0 - p.x0 : x1 - p.x0] = depth_m[y0:y1, x0:x1]
    return out


def pack_masks(masks: np.ndarray | None) -> list[Patch] | None:
    """Full ``bool [M, H, W]`` masks as their tight crops (None stays None): what a whole
    sequence of them keeps in memory."""
    return None if masks is None else [patch_from_mask(m) for m in masks]


def unpack_masks(patches: list[Patch], hw: tuple[int, int]) -> np.ndarray:
    """The full ``bool [M, H, W]`` masks of ``patches`` (:func:`pack_masks`'s inverse)."""
    out = np.zeros((len(patches), *hw), bool)
    for k, p in enumerate(patches):
        out[k] = p.paste(hw)
    return out
