"""The track stage inside a sequence loop: one frame's detections → the masking logic's inputs.

:class:`TrackedSequence` owns the :class:`~slimseg.dynamic.track.Tracker` of one run and does,
per frame, what the stage needs around it: the ORB matches to the previous frame (shared with
the epipolar check), the camera's motion, the tracker's step and, in the epipolar modes, the
check on the tracked objects whose outcome updates each track's moving probability. Both the
``slimseg dynamic`` loop and the cached-detection loop of the sweeps call it, so a setting
gives the same masks in either.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from slimseg.detections import Prediction
from slimseg.dynamic.camera_motion import CameraMotion, estimate_motion
from slimseg.dynamic.epipolar import OrbFeatures, PreviousFrame, match_features
from slimseg.dynamic.pipeline import EPIPOLAR_MODES, FrameInputs, epipolar_evidence
from slimseg.dynamic.semantic import instances_of
from slimseg.dynamic.track import FrameDets, TrackedFrame, Tracker
from slimseg.dynamic.track_settings import TrackSettings
from slimseg.errors import SlimsegError


@dataclass(frozen=True)
class TrackPlan:
    """The track stage of a run: ``settings`` (None: off, the per-frame output) and
    ``segment_every`` N (the model runs on frames 0, N, 2N, ...; tracks carry the masks
    between; needs ``settings``)."""

    settings: TrackSettings | None = None
    segment_every: int = 1

    def __post_init__(self) -> None:
        if self.segment_every < 1:
            raise SlimsegError(f"--segment-every {self.segment_every}: expected 1 or more")
        if self.segment_every > 1 and self.settings is None:
            raise SlimsegError(
                f"--segment-every {self.segment_every} needs --track (the tracks carry the "
                "masks over the frames the model skips)"
            )

    @property
    def on(self) -> bool:
        return self.settings is not None

    def runs_model(self, i: int) -> bool:
        """Does the model run on frame ``i`` (0-based)?"""
        return i % self.segment_every == 0

    def floor(self, conf: float) -> float:
        """The score threshold the model must run at: the masking one, or BYTE's ``low``."""
        return conf if self.settings is None else min(conf, self.settings.low)

    def describe(self) -> str:
        if self.settings is None:
            return "off (per-frame)"
        every = f", model on every {self.segment_every} frames" if self.segment_every > 1 else ""
        return f"{self.settings.describe()}{every}"


def frame_dets(pred: Prediction, hw: tuple[int, int]) -> FrameDets:
    """A prediction (its instances, or a semantic class map's components, each scoring 1) as
    the track stage's detections of an ``hw`` frame."""
    boxes, classes, masks = instances_of(pred)
    scores = pred.scores if pred.class_map is None else np.ones(len(boxes), np.float32)
    return FrameDets(boxes, scores, classes, masks, hw)


class TrackedSequence:
    """Per-frame driver of the track stage for one sequence run in ``mode``."""

    def __init__(
        self, settings: TrackSettings, class_mobility: np.ndarray, mode: str,
        mover_prior: float, fps: float = 30.0,
    ) -> None:  # fmt: skip
        self.tracker = Tracker(settings, class_mobility, fps, mover_prior)
        self.mode = mode
        self.mover_prior = mover_prior
        self.seconds = 0.0
        self.frames = 0
        self.motion_ok = 0

    def inputs(
        self,
        features: OrbFeatures,
        dets: FrameDets | None,
        emit_conf: float,
        depth_m: np.ndarray | None,
        previous: PreviousFrame | None,
    ) -> tuple[FrameInputs, TrackedFrame]:
        """Track one frame (``dets`` None: the model skipped it) and return the masking
        logic's inputs with the tracked objects, and the tracker's output."""
        t0 = time.perf_counter()
        pairs = None  # the epipolar check needs every match; camera motion alone a subset
        if previous is not None and self.mode in EPIPOLAR_MODES:
            pairs = match_features(previous.features, features)
        motion = CameraMotion.identity()
        if previous is not None:
            boxes = [] if dets is None else [np.asarray(dets.boxes).reshape(-1, 4)]
            boxes += [t.kf.box[None] for t in self.tracker.tracks]
            objects = np.concatenate(boxes) if boxes else None
            motion = estimate_motion(previous.features, features, objects, pairs)
        self.motion_ok += motion.ok
        frame = self.tracker.step(dets, motion, emit_conf, depth_m)
        hw = frame.masks.shape[1:] if frame.masks is not None else self.tracker.hw
        inputs = FrameInputs(
            features.keypoints, frame.boxes, frame.classes, frame.masks, tuple(hw), depth_m,
            features.descriptors, previous, frame.mobility, frame.coasted,
        )  # fmt: skip
        if self.mode in EPIPOLAR_MODES and frame.masks is not None:
            ev = epipolar_evidence(inputs, frame.mobility, self.mover_prior, pairs)
            mob = frame.mobility
            if ev.result is not None:
                r = ev.result
                mob = self.tracker.observe_motion(frame, ev.checked, r.decided, r.moving)
            inputs = replace(inputs, mobility=mob, evidence=ev)
        self.seconds += time.perf_counter() - t0
        self.frames += 1
        return inputs, frame

    @property
    def ms_per_frame(self) -> float:
        """Mean time of the stage per frame (matching, camera motion, tracking, the check)."""
        return 1000 * self.seconds / max(self.frames, 1)


TRACK_OFF = TrackPlan()  # every frame judged alone: the output of earlier versions, exactly
