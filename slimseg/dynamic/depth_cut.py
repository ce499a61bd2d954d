"""Masks that stay on their object: the pixels of a mask lying well behind its object are cut.

A low-score mask, or a box that Eq. 4 put in place of a thin mask, spills over the wall or
floor behind the person; the keypoints there are static, and masking them costs SLAM support
for nothing. With depth, the object is where most of its seg mask is: its reference depth is
the median valid depth under the (undilated) seg mask, and every pixel of the region more
than ``band_m`` metres behind it is cut. Pixels without depth (0, NaN) and pixels in front of
the object (an arm reaching out, a carried thing) are kept.
"""

from __future__ import annotations

import numpy as np

# pixels sampled for an object's median depth (a person's thousands of pixels are not needed)
DEPTH_SAMPLES = 400


def reference_depths(masks: np.ndarray, depth_m: np.ndarray) -> np.ndarray:
    """Median valid depth (m) under each of ``masks bool [M, H, W]`` in ``depth_m float32
    [H, W]`` (0 or NaN: no depth) → ``float32 [M]``, NaN where a mask has no valid depth."""
    out = np.full(len(masks), np.nan, np.float32)
    for k, m in enumerate(masks):
        rows = np.flatnonzero(m.any(1))
        if not len(rows):
            continue
        cols = np.flatnonzero(m.any(0))
        crop = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        area = int(m[crop].sum())
        step = max(1, int(np.sqrt(area / DEPTH_SAMPLES)))
        d = depth_m[crop][::step, ::step][m[crop][::step, ::step]]
        d = d[np.isfinite(d) & (d > 0)]
        if len(d):
            out[k] = np.median(d)
    return out


def cut_behind(
    regions: np.ndarray, depth_m: np.ndarray, reference: np.ndarray, band_m: float
) -> np.ndarray:
    """``regions bool [M, H, W]`` without the pixels deeper than ``reference [M] + band_m``
    in ``depth_m [H, W]`` (a NaN reference: the region is kept whole) → ``bool [M, H, W]``
    (a new array; each region is cut on its own bounding crop)."""
    out = regions.copy()
    for k, m in enumerate(regions):
        ref = float(reference[k])
        if not np.isfinite(ref):
            continue
        rows = np.flatnonzero(m.any(1))
        if not len(rows):
            continue
        cols = np.flatnonzero(m.any(0))
        crop = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        d = depth_m[crop]
        with np.errstate(invalid="ignore"):
            behind = d > ref + band_m  # NaN compares False: kept
        out[k][crop] &= ~behind
    return out
