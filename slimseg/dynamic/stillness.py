"""Objects that stood still: a person whose depth has not changed for ``still_frames`` frames
gives its keypoints back (the ``still_frames`` masking setting).

The ``slimseg`` preset masks every person (prior 1, as the papers do), and a person standing
still is static structure a SLAM engine needs: on the held-out synthetic walking sequences
with one, half the keypoints the masks removed were static (docs/slam_defaults.md §5). The
epipolar check of one frame pair cannot tell: a walker who recedes straight from the camera
moves a few centimetres per frame, and the check's residuals on static keypoints are as large
as that. Depth over a longer gap can. Each object's mask pixels (every
:data:`~slimseg.dynamic.occupancy.STRIDE`-th in x and y) are moved, with their depth, into the
camera of an earlier frame (the pose from PnP on the ORB matches:
:func:`~slimseg.dynamic.occupancy.camera_pose`) and compared with the depths that frame saw
within :data:`~slimseg.dynamic.occupancy.NEIGHBOURHOOD_PX` of where they land. A pixel has
*changed* where it lies more than :data:`~slimseg.dynamic.occupancy.TAU_M` nearer than all of
those: something moved in. One more than TAU_M farther than all of them was hidden then, by a
walker passing in front or, for a walker receding, by its own earlier place, and is not
tested. An object is still where at most :data:`STILL_FRACTION` of its tested pixels changed
against both frame ``t - still_frames / 2`` and frame ``t - still_frames``; it then gets
mobility 0. A sequence's first frames hold less history: from ``still_frames / 2`` frames on
the test compares with half and all of what there is (:func:`compared_frames`), because the
first frames are where a SLAM engine builds its first map.

On the synthetic sequences (ground-truth instances, 20-frame window, docs/slam_defaults.md
§5): of the moving persons' keypoints on fourteen walking sequences none was judged still, on
two sitting_static ones 0.4 and 1.5 %, while the standing persons gave back 51–95 % of
theirs. The shorter gaps of frames 10–19 judge more movers still (a third of the sitting
persons' keypoints in those frames, none of the walkers' but on one walking_rpy sequence).
Undecided is dynamic: without depth, a pose, enough tested pixels (:data:`MIN_TESTED`), or
half of ``still_frames`` frames of history, the prior stands.

A verdict is remembered for one frame: an object whose mask overlaps one found still the
frame before (:data:`STILL_MATCH_IOU` on the test's grid) stays still while at most
:data:`STILL_KEEP_FRACTION` of its pixels changed, or while it cannot be tested. A person
standing among walkers is where the test fails: a walker passing beside or behind them at
their depth falls inside the model's mask of the standing person and 10-40 % of that mask
changes for a few frames. On six held-out sequences and four models (shipped preset), the
memory raised keypoint precision on 23 of 24 pairs by up to 8.3 points (walking_xyz s131
58.7 -> 60.6 % for the demo's AMD model, sitting_static 55.8 -> 64.1 % for its Intel one)
for at most 1.0 point of recall, and left ORB-SLAM3's ATE where it was
(docs/standing_person.md); with ground-truth identities, none of the walkers' or seated
persons' mask area was kept still by it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import cv2
import numpy as np

from slimseg.dynamic.epipolar import OrbFeatures, PnpPose, PreviousFrame
from slimseg.dynamic.occupancy import (
    NEIGHBOURHOOD_PX,
    STRIDE,
    TAU_M,
    camera_pose,
    warp_grid,
)

if TYPE_CHECKING:
    from slimseg.dynamic.frame_inputs import FrameInputs

STILL_FRACTION = 0.05  # an object with at most this fraction of its pixels changed is still
MIN_TESTED = 100  # grid pixels (every STRIDE-th in x and y) an object needs to be judged
# an object whose mask overlaps (IoU on the grid) one found still the frame before stays still
# while at most STILL_KEEP_FRACTION of its pixels changed, or while it cannot be tested
STILL_KEEP_FRACTION = 0.3
STILL_MATCH_IOU = 0.5


def depth_span(depth_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi) float32 [H, W]``: the nearest and the farthest depth within
    :data:`~slimseg.dynamic.occupancy.NEIGHBOURHOOD_PX` of each pixel of ``depth_m [H, W]``
    (NaN where that neighbourhood holds a pixel without depth)."""
    d = np.asarray(depth_m, np.float32)
    d = np.where(np.isfinite(d) & (d > 0), d, np.float32(0.0))
    kernel = np.ones((2 * NEIGHBOURHOOD_PX + 1,) * 2, np.uint8)
    lo = cv2.erode(d, kernel)
    hole = lo <= 0
    hi = cv2.dilate(d, kernel)
    lo[hole] = np.nan
    hi[hole] = np.nan
    return lo, hi


def changed_fractions(
    depth_m: np.ndarray, earlier: PreviousFrame, pose: PnpPose, masks: np.ndarray
) -> np.ndarray:
    """``float64 [M]``: of each mask's pixels in ``masks bool [M, H, W]`` with depth in
    ``depth_m [H, W]`` (tested on the grid of every STRIDE-th pixel), moved into the
    ``earlier`` frame's camera by ``pose``, the fraction that lies more than TAU_M nearer than
    every depth that frame saw around there (:func:`depth_span`): something moved in. Pixels
    more than TAU_M farther than every such depth were hidden then and are not tested. NaN
    where fewer than :data:`MIN_TESTED` could be tested."""
    out = np.full(len(masks), np.nan)
    if earlier.depth_m is None or earlier.camera is None or not len(masks):
        return out
    ys, xs, u, v, z = warp_grid(depth_m, earlier.camera, pose, masks.any(0))
    if not len(z):
        return out
    # the span around where they land only: a crop of the earlier depth, not the whole frame
    h, w = earlier.depth_m.shape
    r = NEIGHBOURHOOD_PX
    x0, y0 = max(int(u.min()) - r, 0), max(int(v.min()) - r, 0)
    x1, y1 = min(int(u.max()) + r + 1, w), min(int(v.max()) + r + 1, h)
    lo, hi = depth_span(earlier.depth_m[y0:y1, x0:x1])
    low, high = lo[v - y0, u - x0], hi[v - y0, u - x0]
    with np.errstate(invalid="ignore"):
        # the earlier frame saw nearer all around: the pixel was hidden then (a walker passing
        # in front, or the object's own earlier place as it recedes): not tested
        valid = np.isfinite(low) & (z <= high + TAU_M)
        changed = valid & (z < low - TAU_M)  # it saw farther: something moved in
    for k, m in enumerate(masks):
        on = m[::STRIDE, ::STRIDE][ys, xs] & valid
        n = int(on.sum())
        if n >= MIN_TESTED:
            out[k] = float((changed & on).sum()) / n
    return out


def compared_frames(
    history: Sequence[PreviousFrame], still_frames: int
) -> tuple[PreviousFrame, ...]:
    """The frames ``t - n // 2`` and ``t - n`` of ``history`` (oldest first, ``history[-1]``
    is frame ``t - 1``), ``n`` the frames it holds up to ``still_frames``; empty until it
    holds half of them. A sequence's first frames are where a SLAM engine builds its first
    map: a person standing still from the start is given back from frame ``still_frames / 2``
    on, not ``still_frames`` (docs/slam_defaults.md §5)."""
    n = min(len(history), still_frames)
    if still_frames <= 0 or n < (still_frames + 1) // 2:
        return ()
    return (history[-(n // 2 or 1)], history[-n])


def grid_iou(masks: np.ndarray, before: np.ndarray) -> np.ndarray:
    """``float64 [M, S]``: the IoU of each of ``masks bool [M, H, W]`` with each of ``before
    bool [S, H, W]``, counted on the grid of every STRIDE-th pixel in x and y."""
    a = masks[:, ::STRIDE, ::STRIDE].reshape(len(masks), -1).astype(np.float64)
    b = before[:, ::STRIDE, ::STRIDE].reshape(len(before), -1).astype(np.float64)
    inter = a @ b.T
    union = a.sum(1)[:, None] + b.sum(1)[None] - inter
    return np.where(union > 0, inter / np.maximum(union, 1), 0.0)


def still_objects(
    depth_m: np.ndarray,
    current: OrbFeatures,
    earlier: Sequence[PreviousFrame],
    masks: np.ndarray,
    candidates: np.ndarray,
    before: np.ndarray | None = None,
) -> np.ndarray:
    """``bool [M]``: the ``candidates bool [M]`` whose ``masks bool [M, H, W]`` changed in at
    most :data:`STILL_FRACTION` of their pixels against every frame of ``earlier``; or, where
    a mask overlaps one of ``before bool [S, H, W]`` (the masks found still the frame before)
    with an IoU of at least :data:`STILL_MATCH_IOU`, in at most :data:`STILL_KEEP_FRACTION`
    (or could not be tested: the verdict stands). All False when one of those frames has no
    pose to the ``current`` features."""
    cand = np.asarray(candidates, bool)
    known = np.zeros(len(cand), bool)
    if before is not None and len(before) and cand.any():
        known[cand] = (grid_iou(masks[cand], before) >= STILL_MATCH_IOU).any(1)
    limit = np.where(known, STILL_KEEP_FRACTION, STILL_FRACTION)
    frac = np.where(cand, 0.0, np.inf)
    for frame in earlier:
        pick = np.flatnonzero(frac <= limit)
        if not len(pick):
            break
        pose = camera_pose(frame, current)
        if pose is None:
            return np.zeros(len(cand), bool)
        f = changed_fractions(depth_m, frame, pose, masks[pick])
        # NaN (too few pixels tested): undecided, dynamic; a remembered object keeps its verdict
        f = np.where(np.isnan(f), np.where(known[pick], 0.0, np.inf), f)
        frac[pick] = np.maximum(frac[pick], f)
    return frac <= limit


def find_still(
    inputs: FrameInputs,
    earlier: Sequence[PreviousFrame],
    mobility: np.ndarray,
    before: np.ndarray | None = None,
) -> np.ndarray | None:
    """``bool [M]``: the frame's objects with ``mobility [M]`` above 0 that
    :func:`still_objects` finds still against the ``earlier`` frames
    (:func:`compared_frames`), ``before`` the masks found still the frame before; None where
    the test cannot run: no earlier frames, no depth, no ORB descriptors (the caller's
    keypoints) or no instance masks."""
    masks, depth = inputs.objects.masks, inputs.depth_m
    if not earlier or masks is None or depth is None or inputs.descriptors is None:
        return None
    current = OrbFeatures(np.asarray(inputs.keypoints, np.float32).reshape(-1, 2),
                          inputs.descriptors)  # fmt: skip
    return still_objects(depth, current, earlier, np.asarray(masks, bool), mobility > 0, before)
