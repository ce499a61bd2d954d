"""The per-frame masking chain, once: frame → model feed → ORB → track stage → Eq. 1/3/4 → mask.

:class:`FrameMasker` is what a SLAM loop calls per frame (``step``) and what every slimseg
command is a loop over (``slimseg dynamic``, ``predict --track``, ``slam-eval`` and its sweeps,
the demo, the benchmarks). It runs one mode, configured by one
:class:`~slimseg.dynamic.chain_config.ChainConfig`, and owns what that needs: the model's
schedule (:class:`~slimseg.dynamic.model_feed.ModelFeed`), the ORB features, the previous
frame the epipolar check and the camera motion need, and the track stage. It scores nothing:
each :class:`MaskedFrame` carries what the rules saw (``inputs``), and a report scores the
other modes on that trace (``slimseg.sequence``). The public object configured from an exported
model is :class:`slimseg.Masker` (``slimseg.deploy.masker``); this one takes any
:data:`Segmenter` (a predictor, ground-truth instances, cached detections).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from slimseg.data.tum import depth_metres
from slimseg.detections import Prediction
from slimseg.dynamic.annotations import AnnotationInstances
from slimseg.dynamic.chain_config import ChainConfig
from slimseg.dynamic.epipolar import OrbFeatures, PreviousFrame, orb_features
from slimseg.dynamic.frame_inputs import FrameInputs, MotionEvidence
from slimseg.dynamic.model_feed import Feed, ModelFeed
from slimseg.dynamic.modes import EPIPOLAR_MODES, WEIGHED_MODES
from slimseg.dynamic.pipeline import (
    FrameResult,
    FrameRules,
    epipolar_priors,
    process_frame,
    weighed_mobility,
)
from slimseg.dynamic.seg_box import T_O
from slimseg.dynamic.semantic import objects_of
from slimseg.dynamic.stillness import compared_frames, find_still
from slimseg.dynamic.track_run import TrackedSequence
from slimseg.errors import SlimsegError
from slimseg.objects import Objects

Segmenter = Callable[[np.ndarray, float, float], Objects]
"""The model as the chain calls it: ``(rgb uint8 [H, W, 3], stamp s, conf) -> Objects``
(detections scoring above ``conf``, in frame pixels)."""
Extractor = Callable[[np.ndarray, float], OrbFeatures]
"""The ORB features of a frame as the chain asks for them: ``(rgb uint8 [H, W, 3], stamp s)
-> OrbFeatures`` (the default extracts them; a sweep's cache looks them up)."""

log = logging.getLogger(__name__)


class FrameError(SlimsegError):
    """A frame the chain cannot take (dtype, shape, a size change, a depth of another size)."""


@dataclass(frozen=True)
class FrameTiming:
    """Milliseconds of one frame by part, on the caller's thread: ``model`` (inline runs, or
    waiting for the worker), ORB ``features``, the ``track`` stage, the mode's ``logic``
    (Eq. 1/3/4); ``latency``: from the call to the mask being ready."""

    model: float
    features: float
    track: float
    logic: float
    latency: float

    @property
    def masking(self) -> float:
        """Everything but the model: ORB + track stage + the mode's logic."""
        return self.features + self.track + self.logic


@dataclass(frozen=True)
class MaskedFrame:
    """One frame's outcome: ``mask uint8 [H, W]`` (255 = dynamic, drop features there) and
    ``dynamic bool [N]`` per keypoint; ``lag``: a model result arrived this frame, computed
    that many frames ago (None: none arrived); the mode's ``result`` (Eq. 1's threshold,
    dropped objects, Eq. 4 decisions); ``inputs``: what the rules saw (the keypoints, the
    objects, depth, the previous frame): the trace a report scores other modes on."""

    index: int
    stamp: float
    mask: np.ndarray
    dynamic: np.ndarray
    lag: int | None
    timing: FrameTiming
    result: FrameResult
    inputs: FrameInputs

    @property
    def keypoints(self) -> np.ndarray:
        """``float32 [N, 2]`` (x, y) px: the caller's, or the chain's ORB."""
        return self.inputs.keypoints

    @property
    def objects(self) -> Objects:
        """The objects the rules judged (their ``mobility`` as Eq. 1 used it)."""
        return self.inputs.objects

    @property
    def model_ran(self) -> bool:
        """A model result arrived this frame."""
        return self.lag is not None


class FrameMasker:
    """The chain for one sequence: call :meth:`step` once per frame, in order; :meth:`close`
    (or ``with``) at the end stops the model's worker thread."""

    def __init__(
        self,
        segmenter: Segmenter,
        class_mobility: Sequence[float] | np.ndarray,
        config: ChainConfig | None = None,
        extractor: Extractor | None = None,
        feed: Feed | None = None,
    ) -> None:
        """``segmenter``: the model; ``class_mobility [K]``: priors per class; ``config``:
        mode, settings, track stage and rate, ORB count, camera, fps, depth scale (None: the
        defaults); ``extractor``: the ORB features of a frame (None: extract
        ``config.keypoints`` of them); ``feed``: the model's results by frame (None: the
        segmenter on ``config.track.rate``'s schedule)."""
        self.config = config = config or ChainConfig()
        self.mobility = np.asarray(class_mobility, np.float32)
        self.rules = FrameRules(self.mobility, config.mode, config.masking)
        self.stage = None
        if config.track.on:
            self.stage = TrackedSequence(
                config.track.settings, self.mobility, mode=config.mode,
                mover_prior=self.rules.mover_prior, fps=config.fps,
                motion_odds=config.masking.motion_odds,
            )  # fmt: skip
        degrade = config.masking.rule == "degrade"  # the corners: its static support
        self.extract = extractor or (
            lambda rgb, stamp: orb_features(rgb, config.keypoints, corners=degrade)
        )
        floor = config.floor
        self.feed = feed or ModelFeed(lambda rgb, s: segmenter(rgb, s, floor), config.track.rate)
        self.frames = 0
        self._rng = np.random.default_rng(0)  # depth-RANSAC's sampling
        # the last frames' features (and depth): the previous one, the stillness test's
        self._history: deque[PreviousFrame] = deque(maxlen=max(1, config.masking.still_frames))
        self._hw: tuple[int, int] | None = None
        self._closed = False
        self._busy = threading.Lock()  # held by the step in progress: overlapping calls refused
        self._told_no_depth = False

    # -- the loop's calls ---------------------------------------------------------------------

    def step(
        self,
        rgb: np.ndarray,
        depth: np.ndarray | None = None,
        stamp: float | None = None,
        keypoints: np.ndarray | None = None,
    ) -> MaskedFrame:
        """Mask one frame: ``rgb uint8 [H, W, 3]``, ``depth [H, W]`` (float metres, 0/NaN =
        none; integer with ``depth_scale``), ``stamp`` s (default: index / fps);
        ``keypoints float32 [N, 2]`` (x, y) px to classify (default: the chain's own ORB).

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
            return self._step(rgb, depth, stamp, keypoints)
        finally:
            self._busy.release()

    def _step(
        self,
        rgb: np.ndarray,
        depth: np.ndarray | None,
        stamp: float | None,
        keypoints: np.ndarray | None,
    ) -> MaskedFrame:
        i, config = self.frames, self.config
        hw = self._check(rgb, depth, keypoints)
        depth_m = self._metres(depth)
        if depth_m is None and config.masking.cut_behind_m > 0 and not self._told_no_depth:
            self._told_no_depth = True
            log.warning(
                "no depth image: the depth cut (cut_behind_m %g) cannot act, so Eq. 4 puts a "
                "box only in place of a seg mask covering at most %g of it (RGB-only masking, "
                "docs/slam_defaults.md §6)", config.masking.cut_behind_m,
                min(config.masking.t_o, T_O),
            )  # fmt: skip
        stamp = i / config.fps if stamp is None else float(stamp)
        t0 = time.perf_counter()
        got = self.feed.frame(i, rgb, stamp)
        t1 = time.perf_counter()
        features = self.extract(rgb, stamp)
        t2 = time.perf_counter()
        previous = self._history[-1] if self._history else None
        if self.stage is None:
            objects = Objects.empty(hw) if got.objects is None else got.objects
            objects = replace(objects, mobility=objects.priors(self.mobility))
            inputs = FrameInputs(
                keypoints=features.keypoints, objects=objects, depth_m=depth_m,
                descriptors=features.descriptors, previous=previous, support=features.corners,
            )  # fmt: skip
        else:
            inputs = self.stage.inputs(
                features, got.objects, config.masking.conf, depth_m, previous, got.lag
            )
        earlier = compared_frames(self._history, config.masking.still_frames)
        if earlier:  # on the chain's own ORB, before the caller's keypoints replace them
            still = find_still(inputs, earlier, inputs.objects.priors(self.mobility))
            inputs = replace(inputs, still=still)
        if keypoints is not None:
            inputs = self._with_keypoints(inputs, np.asarray(keypoints, np.float32))
        t3 = time.perf_counter()
        result = process_frame(inputs=inputs, settings=self.rules, rng=self._rng)
        t4 = time.perf_counter()
        self.feed.other_time(t4 - t1)
        if config.camera is not None:  # the motion layers (and PnP residual) need its depth
            self._history.append(PreviousFrame(
                features, depth_m, config.camera, depth_residual=config.epipolar_depth
            ))  # fmt: skip
        else:
            self._history.append(PreviousFrame(features))
        self.frames += 1
        timing = FrameTiming(
            model=1000 * (t1 - t0), features=1000 * (t2 - t1), track=1000 * (t3 - t2),
            logic=1000 * (t4 - t3), latency=1000 * (t4 - t0),
        )  # fmt: skip
        return MaskedFrame(
            index=i, stamp=stamp, mask=result.mask, dynamic=result.dynamic,
            lag=None if got.objects is None else got.lag, timing=timing, result=result,
            inputs=inputs,
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
            if np.issubdtype(depth.dtype, np.integer) and self.config.depth_scale is None:
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
            return depth_metres(depth, self.config.depth_scale)
        return depth

    def _with_keypoints(self, inputs: FrameInputs, kps: np.ndarray) -> FrameInputs:
        """The caller's keypoints classified instead of the chain's ORB; the epipolar check
        still runs on the chain's own features (it needs their descriptors), as the stillness
        test did before."""
        mode, odds = self.config.mode, self.config.masking.motion_odds
        weighed = mode in WEIGHED_MODES and odds > 1
        if inputs.evidence is None and (mode in EPIPOLAR_MODES or weighed):
            mob = inputs.objects.mobility
            if weighed:  # the evidence weighed in now (a check without result: not again)
                mob = weighed_mobility(inputs, mob, odds)
                evidence = MotionEvidence(None, [])
            else:
                mob, result, checked = epipolar_priors(inputs, mob, self.rules.mover_prior)
                evidence = MotionEvidence(result, checked)
            objects = replace(inputs.objects, mobility=mob)
            inputs = replace(inputs, objects=objects, evidence=evidence)
        return replace(inputs, keypoints=kps, descriptors=None)


class Predicts(Protocol):
    """A detector the chain can run: slimseg's ``Predictor`` (``predict(rgb, conf=...)``)."""

    mobility: Sequence[float]

    def predict(self, rgb: np.ndarray, conf: float) -> Prediction: ...


def segmenter_for(source: Predicts | AnnotationInstances) -> Segmenter:
    """The :data:`Segmenter` of a predictor, or of a synthetic sequence's ground-truth
    instances (``AnnotationInstances``: the frame's instances by stamp, whatever ``conf``):
    its :class:`~slimseg.detections.Prediction` as the chain's objects."""
    if isinstance(source, AnnotationInstances):
        return lambda rgb, stamp, conf: objects_of(source.for_stamp(stamp), rgb.shape[:2])
    return lambda rgb, stamp, conf: objects_of(source.predict(rgb, conf=conf), rgb.shape[:2])
