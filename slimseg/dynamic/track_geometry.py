"""Box and mask geometry of the track stage (:mod:`slimseg.dynamic.track`): the camera
motion's scale, box overlaps, a box's share outside the frame, a mask's median depth."""

from __future__ import annotations

import math

import numpy as np

from slimseg.dynamic.camera_motion import CameraMotion
from slimseg.dynamic.mask_patch import Patch, patch_depth

NEAR_IOU = 0.05  # mask IoU only for a detection and a track whose boxes overlap this much
DEPTH_SAMPLES = 400  # pixels sampled for a mask's median depth


def motion_scale(motion: CameraMotion) -> float:
    """The isotropic scale of a similarity ``motion`` (1 for the identity): the same at every
    point, so each box filter need not compute it."""
    if not motion.ok:
        return 1.0
    return float(np.sqrt(abs(np.linalg.det(motion.H[:2, :2]))))


def box_iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``bool [A, B]``: pairs of ``a [A, 4]`` and ``b [B, 4]`` xyxy boxes whose IoU reaches
    :data:`NEAR_IOU` (a mask IoU at the association gates needs far more box overlap)."""
    a, b = a.reshape(-1, 4).astype(np.float64), b.reshape(-1, 4).astype(np.float64)
    iw = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    ih = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    inter = np.clip(iw, 0, None) * np.clip(ih, 0, None)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None] - inter
    return (inter > 0) & (inter >= NEAR_IOU * union)


def box_iou(a: np.ndarray, b: np.ndarray) -> float:
    iw = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    ih = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = iw * ih
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return float(inter / union) if union > 0 else 0.0


def outside_share(box: np.ndarray, hw: tuple[int, int]) -> float:
    """Share of ``box [4]`` xyxy lying outside the ``hw`` frame."""
    area = max(box[2] - box[0], 0) * max(box[3] - box[1], 0)
    if area <= 0:
        return 1.0
    iw = max(0.0, min(box[2], hw[1]) - max(box[0], 0))
    ih = max(0.0, min(box[3], hw[0]) - max(box[1], 0))
    return float(1.0 - iw * ih / area)


def median_depth(patch: Patch, depth_m: np.ndarray | None, fallback: float) -> float:
    """:func:`sampled_median_depth` under the patch's mask, ``fallback`` without any."""
    if depth_m is None or patch.area == 0:
        return fallback
    d = sampled_median_depth(patch_depth(patch, depth_m), patch.mask, patch.area)
    return fallback if math.isnan(d) else d


def sampled_depths(depth: np.ndarray, mask: np.ndarray, area: int) -> np.ndarray:
    """The valid depths (finite, > 0; metres) of ``depth [h, w]`` under ``mask bool [h, w]``
    (``area`` pixels set) on a regular grid of about :data:`DEPTH_SAMPLES` of its pixels (a
    person's thousands of pixels are not needed) → ``[S]``, row-major grid order."""
    k = max(1, int(math.sqrt(area / DEPTH_SAMPLES)))
    d = depth[::k, ::k][mask[::k, ::k]]
    return d[np.isfinite(d) & (d > 0)]


def sampled_median_depth(depth: np.ndarray, mask: np.ndarray, area: int) -> float:
    """Median of :func:`sampled_depths` (metres); NaN without any valid depth."""
    d = sampled_depths(depth, mask, area)
    return float(np.median(d)) if len(d) else math.nan
