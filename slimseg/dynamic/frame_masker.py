"""The per-frame masking chain, once: frame → model feed → ORB → track stage → Eq. 1/3/4 → mask.

:class:`FrameMasker` is what a SLAM loop calls per frame (``step``) and what every slimseg
command is a loop over (``slimseg dynamic``, ``predict --track``, ``slam-eval`` and its sweeps,
the demo, the benchmarks). It owns the model's schedule (:class:`~slimseg.dynamic.model_feed.
ModelFeed` at a :class:`~slimseg.dynamic.model_rate.ModelRate`), the ORB features, the previous
frame the epipolar check and the camera motion need, and the track stage. The public object
configured from an exported model is :class:`slimseg.Masker` (``slimseg.deploy.masker``);
this one takes any :data:`Segmenter` (a predictor, ground-truth instances, cached detections).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from numbers import Integral
from typing import Protocol

import numpy as np

from slimseg.data.tum import depth_metres
from slimseg.data.value_checks import check_intrinsics
from slimseg.detections import Prediction
from slimseg.dynamic.annotations import AnnotationInstances
from slimseg.dynamic.epipolar import OrbFeatures, PreviousFrame, orb_features
from slimseg.dynamic.masking_settings import DEFAULT, MaskingSettings
from slimseg.dynamic.model_feed import Feed, ModelFeed
from slimseg.dynamic.model_rate import EVERY_FRAME, ModelRate
from slimseg.dynamic.pipeline import (
    EPIPOLAR_MODES,
    MODES,
    WEIGHED_MODES,
    FrameInputs,
    FrameResult,
    FrameRules,
    MotionEvidence,
    epipolar_priors,
    process_modes,
    weighed_mobility,
)
from slimseg.dynamic.seg_box import T_O
from slimseg.dynamic.semantic import instances_of
from slimseg.dynamic.track_run import TrackedSequence, frame_dets
from slimseg.dynamic.track_settings import TrackSettings, detection_floor
from slimseg.dynamic.track_types import SOURCE_DETECTION, TrackedFrame
from slimseg.errors import SlimsegError

Segmenter = Callable[[np.ndarray, float, float], Prediction]
"""The model as the chain calls it: ``(rgb uint8 [H, W, 3], stamp s, conf) -> Prediction``
(detections scoring above ``conf``, in frame pixels)."""

BOX_MODES = ("box", "box+depth-ransac")  # modes that work without instance masks
log = logging.getLogger(__name__)


MAX_KEYPOINTS = 100_000  # ORB features per frame (ORB-SLAM uses ~1000): bounds the extractor


class FrameError(SlimsegError):
    """A frame the chain cannot take (dtype, shape, a size change, a depth of another size)."""


@dataclass(frozen=True)
class FrameTiming:
    """Milliseconds of one frame by part, on the caller's thread: ``model`` (inline runs, or
    waiting for the worker), ORB ``features``, the ``track`` stage, the chosen mode's
    ``logic`` (Eq. 1/3/4); ``latency``: from the call to the mask being ready; ``scoring``:
    the other modes run for a report after that (not in ``latency``)."""

    model: float
    features: float
    track: float
    logic: float
    latency: float
    scoring: float = 0.0

    @property
    def masking(self) -> float:
        """Everything but the model: ORB + track stage + the chosen mode's logic."""
        return self.features + self.track + self.logic


@dataclass(frozen=True)
class FrameObjects:
    """The objects the rules judged this frame, frame pixels: ``boxes float32 [M, 4]`` xyxy,
    ``classes int [M]``, ``scores float32 [M]`` (0 for predicted masks), ``mobility float32
    [M]`` (class prior, or the track's moving probability), ``track_ids int [M]`` (-1:
    untracked), ``source [M]`` (det / coast / carried), ``masks bool [M, H, W]`` (None:
    box-only model)."""

    boxes: np.ndarray
    classes: np.ndarray
    scores: np.ndarray
    mobility: np.ndarray
    track_ids: np.ndarray
    source: list[str]
    masks: np.ndarray | None

    def __len__(self) -> int:
        return len(self.boxes)


@dataclass(frozen=True)
class MaskedFrame:
    """One frame's outcome: ``mask uint8 [H, W]`` (255 = dynamic, drop features there),
    ``keypoints float32 [N, 2]`` (the caller's, or the chain's ORB) with ``dynamic bool [N]``,
    the ``objects``; ``model_ran``: a model result arrived this frame, computed ``lag`` frames
    ago; ``results``: the chosen mode's and every scored mode's outcome; ``inputs`` /
    ``tracked`` / ``features``: what the rules saw (reports, overlays); ``prediction``: the
    model result that arrived this frame (None: none), as the model gave it."""

    index: int
    stamp: float
    mask: np.ndarray
    keypoints: np.ndarray
    dynamic: np.ndarray
    objects: FrameObjects
    model_ran: bool
    lag: int
    timing: FrameTiming
    mode: str
    results: dict[str, FrameResult]
    inputs: FrameInputs
    tracked: TrackedFrame | None
    features: OrbFeatures
    prediction: Prediction | None = None

    @property
    def result(self) -> FrameResult:
        """The chosen mode's outcome (Eq. 1's threshold, dropped objects, Eq. 4 decisions)."""
        return self.results[self.mode]


class FrameMasker:
    """The chain for one sequence: call :meth:`step` once per frame, in order; :meth:`close`
    (or ``with``) at the end stops the model's worker thread."""

    def __init__(
        self,
        segmenter: Segmenter,
        *,
        class_mobility: Sequence[float] | np.ndarray,
        mode: str = "fusion",
        masking: MaskingSettings = DEFAULT,
        track: TrackSettings | None = None,
        rate: ModelRate = EVERY_FRAME,
        keypoints: int = 1000,
        camera: tuple[float, float, float, float] | None = None,
        fps: float = 30.0,
        depth_scale: float | None = None,
        score_modes: Sequence[str] = (),
        feed: Feed | None = None,
    ) -> None:
        """``class_mobility [K]``: priors per class; ``mode``: one of
        :data:`~slimseg.dynamic.pipeline.MODES`; ``masking``: the settings (score threshold,
        dilation, Eq. 1/3/4, rule, depth cut); ``track``: the track stage's settings (None:
        every frame judged alone); ``rate``: how often the model runs (other than every frame
        needs ``track``); ``keypoints``: ORB features per frame; ``camera`` ``(fx, fy, cx,
        cy)``: gives the epipolar check the previous depth (PnP residual); ``fps``: the
        sequence's rate (the stage's time constants); ``depth_scale``: units per metre of
        integer depth images (TUM: 5000; float depth is metres); ``score_modes``: other modes
        to run on the same inputs for a report, after the mask is ready; ``feed``: the model
        results of another run to replay (a :class:`~slimseg.dynamic.model_feed.RecordedFeed`,
        any :class:`~slimseg.dynamic.model_feed.Feed`) instead of a schedule
        at ``rate`` (the segmenter then runs not at all)."""
        if mode not in MODES:
            raise SlimsegError(f"mode {mode!r}: expected one of {', '.join(MODES)}")
        bad = [m for m in score_modes if m not in MODES]
        if bad:
            raise SlimsegError(f"score mode {bad[0]!r}: expected one of {', '.join(MODES)}")
        if not rate.every_frame and track is None:
            raise SlimsegError(
                f"model rate '{rate.name}' needs the track stage (track=...): the tracks carry "
                "the masks over the frames without a model result"
            )
        if depth_scale is not None and not (math.isfinite(depth_scale) and depth_scale > 0):
            raise SlimsegError(f"depth_scale {depth_scale}: expected units per metre > 0")
        if (
            isinstance(keypoints, bool)
            or not isinstance(keypoints, Integral)
            or not (1 <= keypoints <= MAX_KEYPOINTS)
        ):
            raise SlimsegError(f"keypoints {keypoints!r}: expected 1 to {MAX_KEYPOINTS} per frame")
        if camera is not None:
            if len(camera) != 4:
                raise SlimsegError(f"camera {camera!r}: expected (fx, fy, cx, cy)")
            names = ("fx", "fy", "cx", "cy")
            check_intrinsics(dict(zip(names, map(float, camera), strict=True)), "camera")
        if (
            isinstance(fps, bool)
            or not isinstance(fps, int | float)
            or not (math.isfinite(fps) and fps > 0)
        ):
            raise SlimsegError(f"fps {fps!r}: expected the sequence's frames per second, > 0")
        self.mobility = np.asarray(class_mobility, np.float32)
        self.mode = mode
        self.masking = masking
        self.track = track
        self.rate = rate
        self.keypoints = keypoints
        self.camera = camera
        self.depth_scale = depth_scale
        self.score_modes = tuple(m for m in score_modes if m != mode)
        self.rules = FrameRules.from_masking(self.mobility, mode, masking)
        self.floor = detection_floor(masking.conf, track)
        """the score threshold the model runs at: the masking one, or BYTE's ``low``"""
        self.stage = None
        if track is not None:
            self.stage = TrackedSequence(
                track, self.mobility, mode=mode, mover_prior=self.rules.mover_prior, fps=fps
            )
        self.fps = fps
        self.frames = 0
        self._paused = 0.0
        self.feed = feed or ModelFeed(
            lambda rgb, s: segmenter(rgb, s, self.floor), rate, self.clock
        )
        self._rng = np.random.default_rng(0)  # depth-RANSAC's sampling
        self._previous: PreviousFrame | None = None
        self._hw: tuple[int, int] | None = None
        self._closed = False
        self._busy = threading.Lock()  # held by the step in progress: overlapping calls refused
        self._told_no_depth = False

    # -- the loop's calls ---------------------------------------------------------------------

    def clock(self) -> float:
        """The loop's clock (s): ``perf_counter`` less the time spent scoring other modes (a
        runtime would not spend it; the model's worker is judged against this clock)."""
        return time.perf_counter() - self._paused

    def step(
        self,
        rgb: np.ndarray,
        depth: np.ndarray | None = None,
        stamp: float | None = None,
        keypoints: np.ndarray | None = None,
        features: OrbFeatures | None = None,
    ) -> MaskedFrame:
        """Mask one frame: ``rgb uint8 [H, W, 3]``, ``depth [H, W]`` (float metres, 0/NaN =
        none; integer with ``depth_scale``), ``stamp`` s (default: index / fps);
        ``keypoints float32 [N, 2]`` (x, y) px to classify (default: the chain's own ORB);
        ``features``: this frame's ORB features when already computed (a cache).

        One frame at a time, in order: a step while another is in progress (from another
        thread) is refused, and so is a step after :meth:`close` (``SlimsegError``)."""
        if self._closed:
            raise SlimsegError("step() after close(): this masker is closed; build a new one")
        if not self._busy.acquire(blocking=False):
            raise SlimsegError(
                "step() while another step() of this masker is in progress: a masker masks one "
                "sequence, one frame at a time; give each thread its own masker"
            )
        try:
            return self._step(rgb, depth, stamp, keypoints, features)
        finally:
            self._busy.release()

    def _step(
        self,
        rgb: np.ndarray,
        depth: np.ndarray | None,
        stamp: float | None,
        keypoints: np.ndarray | None,
        features: OrbFeatures | None,
    ) -> MaskedFrame:
        i = self.frames
        hw = self._check(rgb, depth, keypoints)
        depth_m = self._metres(depth)
        if depth_m is None and self.masking.cut_behind_m > 0 and not self._told_no_depth:
            self._told_no_depth = True
            log.warning(
                "no depth image: the depth cut (cut_behind_m %g) cannot act, so Eq. 4 puts a "
                "box only in place of a seg mask covering at most %g of it (RGB-only masking, "
                "docs/slam_defaults.md §6)", self.masking.cut_behind_m,
                min(self.masking.t_o, T_O),
            )  # fmt: skip
        stamp = i / self.fps if stamp is None else float(stamp)
        t0 = time.perf_counter()
        got = self.feed.frame(i, rgb, stamp)
        t1 = time.perf_counter()
        degrade = self.masking.rule == "degrade"
        if features is None:  # the corners are the degrading rule's static support
            features = orb_features(rgb, self.keypoints, corners=degrade)
        t2 = time.perf_counter()
        previous = self._previous
        tracked = None
        if self.stage is None:
            boxes, classes, masks = instances_of(got.pred)  # semantic: one per component
            scores = got.pred.scores if got.pred.class_map is None else None
            inputs = FrameInputs(
                keypoints=features.keypoints, boxes=boxes, classes=classes, masks=masks, hw=hw,
                depth_m=depth_m, descriptors=features.descriptors, previous=previous,
                scores=scores, support=features.corners,
            )  # fmt: skip
        else:
            dets = None if got.pred is None else frame_dets(got.pred, hw)
            inputs, tracked = self.stage.inputs(
                features, dets, self.masking.conf, depth_m, previous, got.lag
            )
        if keypoints is not None:
            inputs = self._with_keypoints(inputs, np.asarray(keypoints, np.float32))
        t3 = time.perf_counter()
        modes = [self.mode, *self._scored(inputs)]
        results = process_modes(inputs=inputs, settings=self.rules, modes=modes, rng=self._rng)
        chosen = results[self.mode].seconds
        ready = t3 + chosen
        scoring = sum(r.seconds for m, r in results.items() if m != self.mode)
        self._paused += scoring
        self.feed.other_time(ready - t1)
        if self.camera is not None:
            self._previous = PreviousFrame(features, depth_m, self.camera)
        else:
            self._previous = PreviousFrame(features)
        self.frames += 1
        timing = FrameTiming(
            model=1000 * (t1 - t0), features=1000 * (t2 - t1), track=1000 * (t3 - t2),
            logic=1000 * chosen, latency=1000 * (ready - t0), scoring=1000 * scoring,
        )  # fmt: skip
        res = results[self.mode]
        return MaskedFrame(
            index=i, stamp=stamp, mask=res.mask, keypoints=inputs.keypoints,
            dynamic=res.dynamic, objects=self._objects(inputs, tracked),
            model_ran=got.pred is not None, lag=got.lag, timing=timing, mode=self.mode,
            results=results, inputs=inputs, tracked=tracked, features=features,
            prediction=got.pred,
        )  # fmt: skip

    def close(self) -> None:
        """Wait for a model run still in flight and stop the worker; :meth:`step` refuses
        to run afterwards (closing twice is harmless)."""
        self._closed = True
        self.feed.close()

    def __enter__(self) -> FrameMasker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- inside -------------------------------------------------------------------------------

    def _check(
        self, rgb: np.ndarray, depth: np.ndarray | None, keypoints: np.ndarray | None
    ) -> tuple[int, int]:
        """The frame's ``(h, w)``; a :class:`FrameError` names what is wrong."""
        i = self.frames
        shape = rgb.shape if isinstance(rgb, np.ndarray) else ()
        if len(shape) != 3 or shape[2] != 3 or rgb.dtype != np.uint8:
            what = f"{rgb.dtype} {list(rgb.shape)}" if isinstance(rgb, np.ndarray) else type(rgb)
            raise FrameError(f"frame {i}: rgb is {what}, expected uint8 [H, W, 3] (RGB order)")
        hw = (int(rgb.shape[0]), int(rgb.shape[1]))
        if self._hw is not None and hw != self._hw:
            raise FrameError(
                f"frame {i}: {hw[1]}x{hw[0]}, the first frame was {self._hw[1]}x{self._hw[0]}; "
                "one masker serves one camera stream (open another for another size)"
            )
        if depth is not None:
            if not isinstance(depth, np.ndarray) or depth.shape != hw:
                got = list(depth.shape) if isinstance(depth, np.ndarray) else type(depth)
                raise FrameError(f"frame {i}: depth is {got}, expected [H, W] = {list(hw)}")
            if np.issubdtype(depth.dtype, np.integer) and self.depth_scale is None:
                raise FrameError(
                    f"frame {i}: depth is {depth.dtype}: give depth_scale (units per metre, "
                    "TUM: 5000) or pass float metres"
                )
            kind = depth.dtype.kind
            if kind not in "uif":
                raise FrameError(f"frame {i}: depth is {depth.dtype}, expected float or uint16")
        if keypoints is not None:
            kp = np.asarray(keypoints)
            if kp.ndim != 2 or kp.shape[1] != 2 or not np.isfinite(kp).all():
                raise FrameError(f"frame {i}: keypoints {list(kp.shape)}, expected finite [N, 2]")
        self._hw = hw
        return hw

    def _metres(self, depth: np.ndarray | None) -> np.ndarray | None:
        if depth is None:
            return None
        if np.issubdtype(depth.dtype, np.integer):
            return depth_metres(depth, self.depth_scale)
        return depth

    def _scored(self, inputs: FrameInputs) -> list[str]:
        """The score modes this frame allows (instance masks, depth for depth-RANSAC)."""
        out = []
        for m in self.score_modes:
            if inputs.masks is None and m not in BOX_MODES:
                continue
            if m == "box+depth-ransac" and inputs.depth_m is None:
                continue
            out.append(m)
        return out

    def _with_keypoints(self, inputs: FrameInputs, kps: np.ndarray) -> FrameInputs:
        """The caller's keypoints classified instead of the chain's ORB; the epipolar check
        still runs on the chain's own features (it needs their descriptors)."""
        weighed = self.mode in WEIGHED_MODES and self.rules.motion_odds > 1
        if inputs.evidence is None and (self.mode in EPIPOLAR_MODES or weighed):
            mob = inputs.mobility
            if mob is None:
                mob = self.mobility[np.asarray(inputs.classes, int)]
            if weighed:  # the evidence weighed in now (a check without result: not again)
                mob = weighed_mobility(inputs, mob, self.rules.motion_odds)
                evidence = MotionEvidence(None, [])
            else:
                mob, result, checked = epipolar_priors(inputs, mob, self.rules.mover_prior)
                evidence = MotionEvidence(result, checked)
            inputs = replace(inputs, mobility=mob, evidence=evidence)
        return replace(inputs, keypoints=kps, descriptors=None)

    def _objects(self, inputs: FrameInputs, tracked: TrackedFrame | None) -> FrameObjects:
        n = len(inputs.boxes)
        mob = inputs.mobility
        if mob is None:
            mob = self.mobility[np.asarray(inputs.classes, int)]
        scores = np.ones(n, np.float32) if inputs.scores is None else inputs.scores
        return FrameObjects(
            boxes=np.asarray(inputs.boxes, np.float32).reshape(n, 4),
            classes=np.asarray(inputs.classes, np.int64),
            scores=np.asarray(scores, np.float32),
            mobility=np.asarray(mob, np.float32),
            track_ids=np.full(n, -1, np.int64) if tracked is None else tracked.track_ids,
            source=[SOURCE_DETECTION] * n if tracked is None else list(tracked.source),
            masks=inputs.masks,
        )


class Predicts(Protocol):
    """A detector the chain can run: slimseg's ``Predictor`` (``predict(rgb, conf=...)``)."""

    mobility: Sequence[float]

    def predict(self, rgb: np.ndarray, conf: float) -> Prediction: ...


def segmenter_for(source: Predicts | AnnotationInstances) -> Segmenter:
    """The :data:`Segmenter` of a predictor, or of a synthetic sequence's ground-truth
    instances (``AnnotationInstances``: the frame's instances by stamp, whatever ``conf``)."""
    if isinstance(source, AnnotationInstances):
        return lambda rgb, stamp, conf: source.for_stamp(stamp)
    return lambda rgb, stamp, conf: source.predict(rgb, conf=conf)
