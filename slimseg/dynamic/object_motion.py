"""Each object's own motion between two frames, from the ORB matches inside its mask.

A model on its own thread delivers results a few frames late (docs/tracking.md §6). Moving a
late result by the camera motion and then by its track's box-filter velocity fails when the
camera circles a walker: the walker's image motion is neither the background's nor a constant
velocity. The frame the result was computed on has its ORB features already (the loop
computed them when it masked that frame): matching those inside each detection's mask to the
current frame's features measures where the object itself went, whatever moved it.
"""

from __future__ import annotations

import numpy as np

from slimseg.dynamic.epipolar import OrbFeatures, match_features


def object_shifts(
    old: OrbFeatures,
    new: OrbFeatures,
    masks: np.ndarray | None,
    boxes: np.ndarray,
    min_matches: int,
) -> np.ndarray:
    """``float64 [M, 2]`` (dx, dy) px from the ``old`` frame to the ``new`` one, per object:
    the median displacement of the ratio-test matches of ``old``'s keypoints inside the
    object's mask (``masks bool [M, H, W]`` of the old frame; None: inside ``boxes [M, 4]``
    xyxy); NaN where fewer than ``min_matches`` matched (the caller falls back)."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    out = np.full((len(boxes), 2), np.nan)
    kps = old.keypoints
    if len(boxes) == 0 or len(kps) == 0 or min_matches < 1:
        return out
    if masks is None:
        x, y = kps[:, 0][None], kps[:, 1][None]
        inside = (x >= boxes[:, :1]) & (x < boxes[:, 2:3]) & (y >= boxes[:, 1:2]) & (
            y < boxes[:, 3:4])  # fmt: skip
    else:
        h, w = masks.shape[1:]
        xi = np.clip(np.round(kps[:, 0]).astype(int), 0, w - 1)
        yi = np.clip(np.round(kps[:, 1]).astype(int), 0, h - 1)
        inside = masks[:, yi, xi]  # [M, N]
    on_objects = np.flatnonzero(inside.any(0))
    if len(on_objects) < min_matches:
        return out
    sub = OrbFeatures(kps[on_objects], old.descriptors[on_objects])
    pairs = match_features(sub, new)
    if len(pairs) < min_matches:
        return out
    src = on_objects[pairs[:, 0]]
    moved = new.keypoints[pairs[:, 1]].astype(np.float64) - kps[src]
    for k in range(len(boxes)):
        mine = inside[k, src]
        if mine.sum() >= min_matches:
            out[k] = np.median(moved[mine], axis=0)
    return out
