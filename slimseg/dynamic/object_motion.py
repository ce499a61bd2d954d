"""Each object's own motion between two frames, from the ORB matches inside its mask.

A model on its own thread delivers results a few frames late, and between its results the
track stage carries every mask (docs/tracking.md §6). Moving a mask by the camera motion and
then by its track's box-filter velocity fails when the camera circles a walker: the walker's
image motion is neither the background's nor a constant velocity. Both frames have their ORB
features already (the loop computed them when it masked each frame): matching the earlier
frame's keypoints inside the object's mask to the later frame's measures where the object
itself went, whatever moved it. The track stage uses it for late results (the detection's
frame → now) and for every track from one frame to the next.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from slimseg.dynamic.epipolar import OrbFeatures, match_features
from slimseg.dynamic.mask_patch import Patch


def inside_boxes(boxes: np.ndarray, kps: np.ndarray) -> np.ndarray:
    """``bool [M, N]``: keypoint ``kps [N, 2]`` inside ``boxes [M, 4]`` xyxy (box-only)."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    x, y = kps[:, 0][None], kps[:, 1][None]
    return (x >= b[:, :1]) & (x < b[:, 2:3]) & (y >= b[:, 1:2]) & (y < b[:, 3:4])


def inside_patches(patches: Sequence[Patch], kps: np.ndarray) -> np.ndarray:
    """``bool [M, N]``: keypoint ``kps [N, 2]`` on each mask patch."""
    out = np.zeros((len(patches), len(kps)), bool)
    for k, p in enumerate(patches):
        out[k] = p.contains(kps)
    return out


def object_shifts(
    old: OrbFeatures, new: OrbFeatures, inside: np.ndarray, min_matches: int
) -> np.ndarray:
    """``float64 [M, 2]`` (dx, dy) px from the ``old`` frame to the ``new`` one, per object:
    the median displacement of the ratio-test matches of ``old``'s keypoints that lie on the
    object (``inside bool [M, N]`` over ``old.keypoints``:
    :func:`slimseg.dynamic.threshold.inside`, :func:`inside_boxes`, :func:`inside_patches`);
    NaN where fewer than ``min_matches`` matched (the caller falls back)."""
    out = np.full((len(inside), 2), np.nan)
    kps = old.keypoints
    if len(inside) == 0 or len(kps) == 0 or min_matches < 1:
        return out
    on_objects = np.flatnonzero(inside.any(0))
    if len(on_objects) < min_matches:
        return out
    pairs = match_features(OrbFeatures(kps[on_objects], old.descriptors[on_objects]), new)
    if len(pairs) < min_matches:
        return out
    src = on_objects[pairs[:, 0]]
    moved = new.keypoints[pairs[:, 1]].astype(np.float64) - kps[src]
    mine = inside[:, src]  # [M, P]: the matches on each object
    enough = mine.sum(1) >= min_matches
    if enough.any():
        out[enough] = np.stack(
            [
                _subset_medians(moved[:, 0], mine[enough]),
                _subset_medians(moved[:, 1], mine[enough]),
            ],
            axis=1,
        )
    return out


def _subset_medians(values: np.ndarray, members: np.ndarray) -> np.ndarray:
    """``float64 [M]``: the median of ``values [P]`` over each row's ``members bool [M, P]``
    (every row non-empty), all rows at once: the values sorted once, each row's middle
    one (two) found by counting its members in sorted order."""
    order = np.argsort(values, kind="stable")
    ranked = members[:, order]
    count = ranked.sum(1)
    seen = np.cumsum(ranked, axis=1)
    lo = np.argmax(seen >= ((count + 1) // 2)[:, None], axis=1)
    hi = np.argmax(seen >= (count // 2 + 1)[:, None], axis=1)
    v = values[order]
    return 0.5 * (v[lo] + v[hi])
