"""Masks that stay on their object: the pixels of a mask lying well behind its object are cut.

A low-score mask, or a box that Eq. 4 put in place of a thin mask, spills over the wall or
floor behind the person; the keypoints there are static, and masking them costs SLAM support
for nothing. With depth, the object is the nearest layer of its seg mask: a mover stands in
front of the room it moves through, and a coarse seg mask (a 320-px model's prototypes on a
640×480 frame) often holds more wall than person. Its reference depth is therefore a low
order statistic, the :data:`REFERENCE_QUANTILE` quantile of the valid depths under the
(undilated) seg mask, not their median: the median of a mask that is 60 % wall is the wall, and
the box cut to it keeps the wall whole (on the demo's sequence with a model trained on an AMD
CPU, masks covering 65 % of the frame where the walkers cover 17 %; docs/slam_defaults.md §5).
Every pixel of the region more than ``band_m`` metres behind the reference is cut. Pixels
without depth (0, NaN) and pixels in front of it (an arm reaching out, a carried thing) are
kept. Both steps work on each object's box (a detection's mask is zero outside it), so their
cost follows the objects, not the frame. What moved in behind the near layer since the
previous frame is a second layer the cut keeps (:mod:`slimseg.dynamic.occupancy`).
"""

from __future__ import annotations

import numpy as np

from slimseg.dynamic.seg_box import box_spans
from slimseg.dynamic.track_geometry import sampled_depths

# The object's depth: this quantile of the valid depths under its seg mask (the 10 % nearest
# sampled pixels: the person in front, not the wall its coarse mask spills over, nor a few
# noisy pixels). The C++ consumer (export/cpp/src/rules.cpp) mirrors it.
REFERENCE_QUANTILE = 0.1


def reference_depths(masks: np.ndarray, boxes: np.ndarray, depth_m: np.ndarray) -> np.ndarray:
    """The near depth (m) of each of ``masks bool [M, H, W]`` inside its box ``boxes [M, 4]``
    xyxy px, in ``depth_m float32 [H, W]`` (0 or NaN: no depth): of the valid depths sampled
    as the track stage samples them (:func:`~slimseg.dynamic.track_geometry.sampled_depths`),
    sorted, the one at index ``int(REFERENCE_QUANTILE * (S - 1))`` → ``float32 [M]``, NaN
    where a mask has no valid depth."""
    out = np.full(len(masks), np.nan, np.float32)
    for k, (y0, y1, x0, x1) in enumerate(box_spans(boxes, masks.shape[1:])):
        m = masks[k, y0:y1, x0:x1]
        area = int(m.sum())
        if area:
            d = sampled_depths(depth_m[y0:y1, x0:x1], m, area)
            if len(d):
                i = int(REFERENCE_QUANTILE * (len(d) - 1))
                out[k] = np.partition(d, i)[i]
    return out


def cut_behind(
    regions: np.ndarray,
    boxes: np.ndarray,
    depth_m: np.ndarray,
    reference: np.ndarray,
    band_m: float,
    layers: np.ndarray | None = None,
) -> np.ndarray:
    """Cut from each of ``regions bool [M, H, W]`` the pixels inside its box ``boxes [M, 4]``
    that lie deeper than ``reference [M] + band_m`` in ``depth_m [H, W]`` (a NaN reference:
    the region is kept whole), in place, except those within ``band_m`` of the object's motion
    layer ``layers [M]`` m (:func:`slimseg.dynamic.occupancy.motion_layers`; NaN or None:
    none); returns ``regions``."""
    for k, (y0, y1, x0, x1) in enumerate(box_spans(boxes, regions.shape[1:])):
        ref = float(reference[k])
        if not np.isfinite(ref):
            continue
        d = depth_m[y0:y1, x0:x1]
        with np.errstate(invalid="ignore"):
            behind = d > ref + band_m  # NaN compares False: kept
            if layers is not None and np.isfinite(layers[k]):
                behind &= ~(np.abs(d - float(layers[k])) <= band_m)
        regions[k, y0:y1, x0:x1] &= ~behind
    return regions


def behind_pixels(
    boxes: np.ndarray, depth_m: np.ndarray, reference: np.ndarray, band_m: float
) -> np.ndarray:
    """``bool [H, W]``: the pixels inside some box ``boxes [M, 4]`` deeper than that object's
    ``reference [M] + band_m`` in ``depth_m [H, W]``: those the cut may drop."""
    out = np.zeros(depth_m.shape, bool)
    for k, (y0, y1, x0, x1) in enumerate(box_spans(boxes, depth_m.shape)):
        ref = float(reference[k])
        if np.isfinite(ref):
            with np.errstate(invalid="ignore"):
                out[y0:y1, x0:x1] |= depth_m[y0:y1, x0:x1] > ref + band_m
    return out
