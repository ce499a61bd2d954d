"""The track stage inside a sequence loop: one frame's detections → the masking logic's inputs.

:class:`TrackedSequence` owns the :class:`~slimseg.dynamic.track.Tracker` of one run and does,
per frame, what the stage needs around it: the ORB matches to the previous frame (passed on
for the epipolar check), the camera's motion and the tracker's step. The check's decisions
reach the tracks through :func:`slimseg.dynamic.mobility.decide_mobility` (the tracker is its
:class:`~slimseg.dynamic.mobility.MotionBelief`). Both the ``slimseg dynamic`` loop and the
cached-detection loop of the sweeps call it, so a setting gives the same masks in either.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import replace

import numpy as np

from slimseg.dynamic.camera_motion import CameraMotion, estimate_motion
from slimseg.dynamic.epipolar import OrbFeatures, PreviousFrame, match_features
from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.mask_patch import clip_patch, patch_from_mask, warp_patch
from slimseg.dynamic.modes import FPS
from slimseg.dynamic.object_motion import (
    inside_boxes,
    inside_patches,
    object_shifts,
)
from slimseg.dynamic.threshold import inside
from slimseg.dynamic.track import Tracker
from slimseg.dynamic.track_settings import TrackSettings
from slimseg.objects import Objects


def move_dets(dets: Objects, h: np.ndarray, shifts: np.ndarray | None = None) -> Objects:
    """``dets`` of an older frame moved into the current one: by ``h float [3, 3]`` (older →
    current pixels), or by their own ``shifts float [M, 2]`` (dx, dy) px where finite (the
    result's ``own_motion``). Each box goes to the bounds of its moved corners, each mask is
    warped on its crop (nearest neighbour); what leaves the frame is cut."""
    hw = dets.hw
    boxes = dets.boxes
    own = np.zeros(len(boxes), bool) if shifts is None else np.isfinite(shifts).all(1)
    if (np.allclose(h, np.eye(3)) and not own.any()) or len(boxes) == 0:
        return dets
    hs = np.repeat(np.asarray(h, np.float64)[None], len(boxes), 0)
    if own.any():
        hs[own, :2, 2] = np.round(shifts[own])  # whole pixels: masks shift without a warp
        hs[own, :2, :2] = np.eye(2)
    corners = boxes[:, [0, 1, 2, 1, 2, 3, 0, 3]].reshape(-1, 4, 2).astype(np.float64)
    moved = np.einsum("mij,mkj->mki", hs[:, :2, :2], corners) + hs[:, None, :2, 2]
    out = np.concatenate([moved.min(1), moved.max(1)], 1)
    out[:, [0, 2]] = out[:, [0, 2]].clip(0, hw[1])
    out[:, [1, 3]] = out[:, [1, 3]].clip(0, hw[0])
    masks = None
    if dets.masks is not None:
        masks = np.zeros((len(boxes), *hw), bool)
        for k, (m, b) in enumerate(zip(dets.masks, boxes, strict=True)):
            p = patch_from_mask(m, b)
            if own[k]:  # a whole-pixel shift: the warp's nearest neighbour, without a warp
                p = clip_patch(p.moved(int(hs[k, 1, 2]), int(hs[k, 0, 2])), hw)
            else:
                p = warp_patch(p, hs[k], hw)
            masks[k, p.y0 : p.y0 + p.mask.shape[0], p.x0 : p.x0 + p.mask.shape[1]] = p.mask
    return replace(dets, boxes=out.astype(np.float32), masks=masks, own_motion=own)


class TrackedSequence:
    """Per-frame driver of the track stage for one sequence run in ``mode``."""

    def __init__(
        self,
        settings: TrackSettings,
        class_mobility: np.ndarray,
        *,
        mover_prior: float,
        fps: float = FPS,
    ) -> None:
        self.tracker = Tracker(settings, class_mobility, fps=fps, mover_prior=mover_prior)
        self.seconds = 0.0
        self.frames = 0
        self.motion_ok = 0
        self._motions: deque[np.ndarray] = deque(maxlen=MAX_LAG)
        """the last frames' camera motions (previous → current pixels), newest last"""
        self._features: deque[OrbFeatures] = deque(maxlen=MAX_LAG + 1)
        """the last frames' ORB features, newest last (a late result's own motion)"""

    def inputs(
        self,
        features: OrbFeatures,
        dets: Objects | None,
        emit_conf: float,
        depth_m: np.ndarray | None,
        previous: PreviousFrame | None,
        lag: int = 0,
    ) -> FrameInputs:
        """Track one frame (``dets`` None: the model skipped it) and return the masking
        logic's inputs: the tracked objects (their mobility each track's, decided further by
        :func:`~slimseg.dynamic.mobility.decide_mobility`). ``lag``: ``dets``
        were computed ``lag`` frames ago (a model on its own thread); they are moved into
        this frame by the camera motions in between first."""
        t0 = time.perf_counter()
        pairs = None  # matched once: the camera motion and the epipolar check share them
        motion = CameraMotion.identity()
        if previous is not None:
            pairs = match_features(previous.features, features)
            boxes = [] if dets is None else [dets.boxes]
            boxes += [t.kf.box[None] for t in self.tracker.tracks]
            objects = np.concatenate(boxes) if boxes else None
            motion = estimate_motion(previous.features, features, objects, pairs)
        self.motion_ok += motion.ok
        self._motions.append(motion.H if motion.ok else np.eye(3))
        self.tracker.parts["motion"] += time.perf_counter() - t0
        self._features.append(features)
        if dets is not None and lag > 0:
            t1 = time.perf_counter()
            h = np.eye(3)
            for m in list(self._motions)[-lag:]:
                h = m @ h
            shifts = None
            if self.tracker.s.own_matches > 0 and lag < len(self._features):
                old = self._features[-1 - lag]
                kps = old.keypoints
                on = inside_boxes(dets.boxes, kps) if dets.masks is None else inside(
                    kps, dets.masks)  # fmt: skip
                shifts = object_shifts(old, features, on, self.tracker.s.own_matches)
            dets = move_dets(dets, h, shifts)
            self.tracker.parts["lag"] += time.perf_counter() - t1
        own = None
        if previous is not None and self.tracker.s.own_matches > 0 and self.tracker.tracks:
            t2 = time.perf_counter()
            own = self._own_motion(previous.features, features)
            self.tracker.parts["motion"] += time.perf_counter() - t2
        frame = self.tracker.step(dets, motion, emit_conf, depth_m, lag, own)
        inputs = FrameInputs(
            keypoints=features.keypoints, objects=frame, depth_m=depth_m,
            descriptors=features.descriptors, previous=previous, support=features.corners,
            matches=pairs,
        )  # fmt: skip
        self.seconds += time.perf_counter() - t0
        self.frames += 1
        return inputs

    def _own_motion(self, old: OrbFeatures, new: OrbFeatures) -> dict[int, np.ndarray]:
        """Track id → ``(dx, dy)`` px of its object from the previous frame to this one, for
        the tracks with enough ORB matches on their previous-frame mask."""
        tracks, patches = self.tracker.previous_patches()
        if not tracks:
            return {}
        on = inside_patches(patches, old.keypoints)
        shifts = object_shifts(old, new, on, self.tracker.s.own_matches)
        return {t.id: s for t, s in zip(tracks, shifts, strict=True) if np.isfinite(s).all()}

    @property
    def ms_per_frame(self) -> float:
        """Mean time of the stage per frame (matching, camera motion, tracking, the check)."""
        return 1000 * self.seconds / max(self.frames, 1)


MAX_LAG = 30  # frames of camera motion kept for a late model result (older ones: not moved)
