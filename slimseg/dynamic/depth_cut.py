"""Masks that stay on their object: the pixels of a mask lying well behind its object are cut.

A low-score mask, or a box that Eq. 4 put in place of a thin mask, spills over the wall or
floor behind the person; the keypoints there are static, and masking them costs SLAM support
for nothing. With depth, the object is where most of its seg mask is: its reference depth is
the median valid depth under the (undilated) seg mask, and every pixel of the region more
than ``band_m`` metres behind it is cut. Pixels without depth (0, NaN) and pixels in front of
the object (an arm reaching out, a carried thing) are kept. Both steps work on each object's
box (a detection's mask is zero outside it), so their cost follows the objects, not the frame.
"""

from __future__ import annotations

import numpy as np

from slimseg.dynamic.seg_box import box_spans
from slimseg.dynamic.track_geometry import sampled_median_depth


def reference_depths(masks: np.ndarray, boxes: np.ndarray, depth_m: np.ndarray) -> np.ndarray:
    """Median valid depth (m) under each of ``masks bool [M, H, W]`` inside its box
    ``boxes [M, 4]`` xyxy px, in ``depth_m float32 [H, W]`` (0 or NaN: no depth), sampled as
    the track stage samples it (:func:`~slimseg.dynamic.track_geometry.sampled_median_depth`)
    → ``float32 [M]``, NaN where a mask has no valid depth."""
    out = np.full(len(masks), np.nan, np.float32)
    for k, (y0, y1, x0, x1) in enumerate(box_spans(boxes, masks.shape[1:])):
        m = masks[k, y0:y1, x0:x1]
        area = int(m.sum())
        if area:
            out[k] = sampled_median_depth(depth_m[y0:y1, x0:x1], m, area)
    return out


def cut_behind(
    regions: np.ndarray,
    boxes: np.ndarray,
    depth_m: np.ndarray,
    reference: np.ndarray,
    band_m: float,
) -> np.ndarray:
    """Cut from each of ``regions bool [M, H, W]`` the pixels inside its box ``boxes [M, 4]``
    that lie deeper than ``reference [M] + band_m`` in ``depth_m [H, W]`` (a NaN reference:
    the region is kept whole), in place; returns ``regions``."""
    for k, (y0, y1, x0, x1) in enumerate(box_spans(boxes, regions.shape[1:])):
        ref = float(reference[k])
        if not np.isfinite(ref):
            continue
        with np.errstate(invalid="ignore"):
            behind = depth_m[y0:y1, x0:x1] > ref + band_m  # NaN compares False: kept
        regions[k, y0:y1, x0:x1] &= ~behind
    return regions
