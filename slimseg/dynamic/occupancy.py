"""What moved in: pixels a mover now occupies where the previous frame saw farther, and the
depth layer they mark behind an object's near layer (the depth cut's motion layers).

The depth cut (:mod:`slimseg.dynamic.depth_cut`) keeps an object's near layer. A walker seen
behind furniture, or behind a nearer walker, has a coarse mask whose near layer is the thing in
front, and the cut drops the walker whole (12 frames in a row on a walking_static sequence;
docs/slam_defaults.md §5). Two-view evidence says otherwise, but not per keypoint: on the
synthetic walking sequences the matched static keypoints' PnP residuals were above 1 px for
27–49 % of them, so a keypoint vote picked walls as often as walkers.

Dense depth gives sharper evidence. The camera's motion from the previous frame is fitted by
PnP on the ORB matches (:func:`~slimseg.dynamic.epipolar.pnp_pose`; RANSAC leaves the movers
out as outliers). Each candidate pixel of the current frame (every :data:`STRIDE`-th in x and
y) is back-projected with its depth, moved into the previous camera and looked up in the
previous depth image, taking the nearest depth within :data:`NEIGHBOURHOOD_PX` of where it
lands. Where even that is more than :data:`TAU_M` farther, the surface now there was not
there before: something moved into it (the leading edge of a walker). A static scene does
not do this: a surface the camera's own motion uncovers was hidden, so the previous frame saw
*nearer* along its ray, not farther; and the neighbourhood minimum absorbs the fit's
pixel-sized errors along depth edges and on a floor seen at a grazing angle. On the demo's
sequence and a walking_static sequence 98–99 % of the pixels so marked lay on movers (the
ground-truth masks), covering 9–16 % of the movers' pixels. Only pixels inside a surface are
candidates (:func:`surfaces`): thin structures (a chair's legs, a dog's) flicker in a depth
image and were what the rest marked.

An object's motion layer is the median depth of the marked pixels in its box behind its near
layer, where they stand for at least ``motion_layer_px`` frame pixels (the masking setting,
100 in the ``slimseg`` preset, :mod:`slimseg.dynamic.knobs`); the cut then keeps that layer too.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from slimseg.dynamic.epipolar import (
    PNP_MIN_POINTS,
    OrbFeatures,
    PnpPose,
    PreviousFrame,
    match_features,
    pnp_pose,
)
from slimseg.dynamic.seg_box import box_spans

if TYPE_CHECKING:
    from slimseg.dynamic.frame_inputs import FrameInputs
    from slimseg.dynamic.masking_settings import MaskingSettings

TAU_M = 0.2  # the previous frame saw at least this much farther (m): something moved in
NEIGHBOURHOOD_PX = 2  # the previous depth is the nearest within this many px of the landing
SURFACE_PX = 1  # a candidate's depth spans at most TAU_M this many px around: not a sliver
STRIDE = 2  # every STRIDE-th pixel, in x and y, is tested
# Marked frame pixels that make an object's motion layer (the slimseg preset's
# motion_layer_px; docs/slam_defaults.md §5).
# Features per frame the pose is fitted on (:func:`subsample`); docs/slam_defaults.md §5 ("An
# accurate camera pose") says why the stride stays.
MOTION_FEATURES = 300


def subsample(f: OrbFeatures) -> tuple[OrbFeatures, np.ndarray]:
    """At most about :data:`MOTION_FEATURES` of ``f``'s features (a regular stride) and their
    indices in ``f``."""
    step = max(1, -(-len(f.keypoints) // MOTION_FEATURES))
    idx = np.arange(0, len(f.keypoints), step)
    return OrbFeatures(f.keypoints[idx], f.descriptors[idx]), idx


def camera_pose(previous: PreviousFrame, current: OrbFeatures) -> PnpPose | None:
    """The camera's motion from ``previous`` to ``current`` (PnP on the ORB matches with
    previous depth, of the features :func:`subsample` keeps); None without previous depth and
    intrinsics, or without a fit.

    The two strides are drawn independently, so they keep about a sixteenth of the true
    pairs, and the pose is coarse: on walking_static 403, 10 frames apart, a median rotation
    error of 0.33° and 33 mm where all features give 0.066° and 8 mm. The stillness test's
    and the motion layers' thresholds were chosen on this pose; with the accurate one and
    thresholds chosen again, walking_static 403's ATE rose by 12 % over 10 runs, so the
    stride stays (docs/slam_defaults.md §5, "An accurate camera pose")."""
    if previous.depth_m is None or previous.camera is None:
        return None
    a, ia = subsample(previous.features)
    b, ib = subsample(current)
    pairs = match_features(a, b)
    if len(pairs) < PNP_MIN_POINTS:
        return None
    p0 = previous.features.keypoints[ia[pairs[:, 0]]]
    p1 = current.keypoints[ib[pairs[:, 1]]]
    return pnp_pose(p0, p1, np.ones(len(pairs), bool), previous.depth_m, previous.camera)


def nearest_before(previous_depth_m: np.ndarray) -> np.ndarray:
    """``float32 [H, W]``: the nearest valid depth within :data:`NEIGHBOURHOOD_PX` of each
    pixel of ``previous_depth_m [H, W]`` (a grey erosion; NaN where that neighbourhood holds a
    pixel without depth, which then marks nothing)."""
    d = np.nan_to_num(np.asarray(previous_depth_m, np.float32), nan=0.0, posinf=0.0)
    size = 2 * NEIGHBOURHOOD_PX + 1
    near = cv2.erode(d, np.ones((size, size), np.uint8))
    return np.where(near > 0, near, np.float32(np.nan))


def surfaces(depth_m: np.ndarray) -> np.ndarray:
    """``bool [H, W]``: the pixels of ``depth_m [H, W]`` inside a surface, whose depths within
    :data:`SURFACE_PX` all lie within :data:`TAU_M` of one another (none of them invalid).
    Slivers and depth edges are not: a chair's 2-px legs behind a walker flicker in and out of
    a depth image from frame to frame (on a held-out walking_xyz sequence they made every
    false motion layer)."""
    d = np.nan_to_num(np.asarray(depth_m, np.float32), nan=0.0, posinf=0.0)
    size = 2 * SURFACE_PX + 1
    kernel = np.ones((size, size), np.uint8)
    low = cv2.erode(d, kernel)
    return (low > 0) & (cv2.dilate(d, kernel) - low <= TAU_M)


def warp_grid(
    depth_m: np.ndarray, camera: tuple[float, float, float, float], pose: PnpPose,
    where: np.ndarray,
) -> tuple[np.ndarray, ...]:  # fmt: skip
    """The pixels of ``where bool [H, W]`` on the grid of every :data:`STRIDE`-th pixel with
    valid depth in ``depth_m [H, W]`` (metres), moved into the earlier camera of ``pose``
    (``camera (fx, fy, cx, cy)`` px): ``(ys, xs)`` their grid indices and ``(u, v)`` the
    earlier frame's pixel they land on (``int64 [P]``), ``z float32 [P]`` their depth there;
    only those that land inside the frame, in front of the camera."""
    fx, fy, cx, cy = camera
    h, w = depth_m.shape
    grid = depth_m[::STRIDE, ::STRIDE]
    ys, xs = np.nonzero(where[::STRIDE, ::STRIDE])
    z = grid[ys, xs].astype(np.float32)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(z) & (z > 0)
    ys, xs, z = ys[ok], xs[ok], z[ok]
    u0, v0 = xs.astype(np.float32) * STRIDE, ys.astype(np.float32) * STRIDE
    cur = np.stack([(u0 - cx) * z / fx, (v0 - cy) * z / fy, z], 1).reshape(-1, 3)
    r, t = pose.rotation.astype(np.float32), pose.tvec.reshape(1, 3).astype(np.float32)
    prev = (cur - t) @ r  # X_prev = R^T (X_cur - t), as row vectors
    zp = prev[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.round(prev[:, 0] / zp * fx + cx)
        v = np.round(prev[:, 1] / zp * fy + cy)
        seen = (zp > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return (ys[seen], xs[seen], u[seen].astype(np.int64), v[seen].astype(np.int64), zp[seen])


def moved_in(
    depth_m: np.ndarray,
    before: np.ndarray,
    camera: tuple[float, float, float, float],
    pose: PnpPose,
    where: np.ndarray,
) -> np.ndarray:
    """``bool [H', W']`` on the grid of every :data:`STRIDE`-th pixel (``depth_m[::s, ::s]``'s
    shape): the pixels of ``where bool [H, W]`` with valid depth in ``depth_m [H, W]``
    (metres) that the previous frame, ``before`` (:func:`nearest_before` of its depth), saw
    more than :data:`TAU_M` behind along the same ray under ``pose``; ``camera (fx, fy, cx,
    cy)`` px."""
    out = np.zeros(depth_m[::STRIDE, ::STRIDE].shape, bool)
    ys, xs, u, v, zp = warp_grid(depth_m, camera, pose, where)
    with np.errstate(invalid="ignore"):
        farther = before[v, u] > zp + TAU_M  # NaN (no depth near there) compares False
    out[ys[farther], xs[farther]] = True
    return out


def motion_layers(
    marked: np.ndarray,
    boxes: np.ndarray,
    depth_m: np.ndarray,
    reference: np.ndarray,
    band_m: float,
    min_px: int,
) -> np.ndarray:
    """Each object's motion layer (m) → ``float32 [M]``, NaN: none. Of the ``marked bool [H',
    W']`` grid pixels (:func:`moved_in`) inside its box ``boxes [M, 4]`` (frame px) and deeper
    than its near layer ``reference [M] + band_m`` in ``depth_m [H, W]``: their median depth,
    where they stand for at least ``min_px`` frame pixels."""
    out = np.full(len(boxes), np.nan, np.float32)
    grid = depth_m[::STRIDE, ::STRIDE]
    need = max(1, -(-int(min_px) // (STRIDE * STRIDE)))
    spans = box_spans(np.asarray(boxes, np.float32).reshape(-1, 4) / STRIDE, marked.shape)
    for k, (y0, y1, x0, x1) in enumerate(spans):
        ref = float(reference[k])
        if not np.isfinite(ref):
            continue
        d = grid[y0:y1, x0:x1]
        with np.errstate(invalid="ignore"):
            pick = marked[y0:y1, x0:x1] & (d > ref + band_m)
        if int(pick.sum()) >= need:
            out[k] = float(np.median(d[pick]))
    return out


class MotionLayers:
    """One frame's motion layers, for every mode that cuts by depth: the camera's pose and the
    previous depth's neighbourhood minimum are computed once, on first use."""

    def __init__(
        self, depth_m: np.ndarray, previous: PreviousFrame, current: OrbFeatures, min_px: int
    ) -> None:
        self.depth_m, self.previous, self.current, self.min_px = depth_m, previous, current, min_px
        self._ready = False
        self._pose: PnpPose | None = None
        self._before: np.ndarray | None = None
        self._surfaces: np.ndarray | None = None

    @classmethod
    def of(cls, inputs: FrameInputs, masking: MaskingSettings) -> MotionLayers | None:
        """For a frame's ``inputs``; None where they cannot act: ``motion_layer_px`` or the
        depth cut off, no depth, no descriptors (caller's keypoints), or no previous frame
        with depth and intrinsics."""
        prev = inputs.previous
        if masking.motion_layer_px <= 0 or masking.cut_behind_m <= 0:
            return None
        if inputs.depth_m is None or inputs.descriptors is None:
            return None
        if prev is None or prev.depth_m is None or prev.camera is None:
            return None
        kps = np.asarray(inputs.keypoints, np.float32).reshape(-1, 2)
        current = OrbFeatures(kps, inputs.descriptors)
        return cls(inputs.depth_m, prev, current, masking.motion_layer_px)

    def layers(
        self, behind: np.ndarray, boxes: np.ndarray, reference: np.ndarray, band_m: float
    ) -> np.ndarray | None:
        """:func:`motion_layers` of the ``behind bool [H, W]`` pixels (those the cut would
        drop, :func:`~slimseg.dynamic.depth_cut.behind_pixels`) inside a surface
        (:func:`surfaces`); None: no such pixel, or no pose."""
        if self._surfaces is None:  # once per frame, whatever the modes
            self._surfaces = surfaces(self.depth_m)
        behind = behind & self._surfaces
        if not behind.any():
            return None
        if not self._ready:
            self._ready = True
            self._pose = camera_pose(self.previous, self.current)
            if self._pose is not None:
                assert self.previous.depth_m is not None
                self._before = nearest_before(self.previous.depth_m)
        if self._pose is None or self._before is None or self.previous.camera is None:
            return None
        marked = moved_in(self.depth_m, self._before, self.previous.camera, self._pose, behind)
        return motion_layers(marked, boxes, self.depth_m, reference, band_m, self.min_px)
