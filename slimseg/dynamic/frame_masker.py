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
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Protocol

import numpy as np

from slimseg.data.tum import depth_metres
from slimseg.detections import Prediction
from slimseg.dynamic.annotations import AnnotationInstances
from slimseg.dynamic.chain_config import ChainConfig
from slimseg.dynamic.epipolar import OrbFeatures, PreviousFrame, orb_features
from slimseg.dynamic.familiarity import Familiarity
from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.knobs import Rule, Value, unmet
from slimseg.dynamic.masked_frame import FrameTiming, MaskedFrame, StageClock
from slimseg.dynamic.mobility import MotionBelief
from slimseg.dynamic.model_feed import FedDetections, Feed, ModelFeed
from slimseg.dynamic.occupancy import MotionLayers
from slimseg.dynamic.pipeline import FrameRules, apply_rules
from slimseg.dynamic.seg_box import T_O
from slimseg.dynamic.semantic import objects_of
from slimseg.dynamic.stillness import compared_frames, find_still
from slimseg.dynamic.track_belief import TrackBeliefs
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
        self._belief: MotionBelief | None = None  # where the check's decisions go (tracks)
        if config.track.on:
            self.stage = TrackedSequence(
                config.track.settings,
                self.mobility,
                mover_prior=self.rules.mover_prior,
                fps=config.fps,
            )
            self._belief = TrackBeliefs(self.stage.tracker)
        degrade = config.masking.rule == Rule.DEGRADE  # the corners: its static support
        self.extract = extractor or (
            lambda rgb, stamp: orb_features(rgb, config.keypoints, corners=degrade)
        )
        floor = config.floor
        self.feed = feed or ModelFeed(lambda rgb, s: segmenter(rgb, s, floor), config.track.rate)
        self.frames = 0
        self._rng = np.random.default_rng(0)  # depth-RANSAC's sampling
        # the last frames' features (and depth): the previous one, the stillness test's
        self._history: deque[PreviousFrame] = deque(maxlen=max(1, config.masking.still_frames))
        self._still_masks: np.ndarray | None = None  # the masks found still the frame before
        self._hw: tuple[int, int] | None = None
        self._closed = False
        self._busy = threading.Lock()  # held by the step in progress: overlapping calls refused
        self._told_no_depth = False
        self._familiar = config.expect and Familiarity(config.expect, config.masking)
        if config.camera is None:
            self._unmet({"depth", "history", "track"}, "no camera intrinsics (camera=)")

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
        """The chain, one stage after another (:data:`STAGES`)."""
        i, config = self.frames, self.config
        hw = self._check(rgb, depth, keypoints)
        depth_m = self._metres(depth)
        if depth_m is None and not self._told_no_depth:
            self._told_no_depth = True
            self._unmet({"camera", "history", "track"}, f"frame {i}: no depth image")
        stamp = i / config.fps if stamp is None else float(stamp)
        clock = StageClock()
        with clock("model"):  # this frame's model result, if one arrived
            got = self.feed.frame(i, rgb, stamp)
        with clock("features"):  # the chain's own ORB
            features = self.extract(rgb, stamp)
        previous = self._history[-1] if self._history else None
        with clock("objects"):  # the track stage, or the detections with their priors
            inputs = self._objects(hw, features, got, depth_m, previous)
        with clock("stillness"):
            inputs = self._stillness(inputs)
        with clock("mobility"):  # prior or track → stillness → the check's evidence
            decision = self.rules.decide(inputs, belief=self._belief)
        with clock("layers"):  # on the chain's ORB, before the caller's keypoints replace them
            moved = MotionLayers.of(inputs, config.masking)
        if keypoints is not None:
            kps = np.asarray(keypoints, np.float32)
            inputs = replace(inputs, keypoints=kps, descriptors=None, matches=None)
        with clock("rules"):  # regions, depth cut, dilation, Eq. 3/4, the shortfall rule
            result = apply_rules(inputs, decision, self.rules, rng=self._rng, moved=moved)
        self.feed.other_time(clock.since("features"))
        self._remember(features, depth_m)
        if self._familiar and (new := self._familiar.observe(result.mask, result.dynamic)):
            self.config = replace(config, masking=new)  # far looser than calibrated: tighter
            self.rules = FrameRules(self.mobility, config.mode, new)
        self.frames += 1
        return MaskedFrame(
            index=i, stamp=stamp, mask=result.mask, dynamic=result.dynamic,
            lag=None if got.objects is None else got.lag,
            timing=FrameTiming(clock.ms, clock.total_ms()), result=result, inputs=inputs,
            decision=decision,
        )  # fmt: skip

    def _objects(
        self,
        hw: tuple[int, int],
        features: OrbFeatures,
        got: FedDetections,
        depth_m: np.ndarray | None,
        previous: PreviousFrame | None,
    ) -> FrameInputs:
        """The frame's objects: the track stage's (tracked, coasted, carried), or this frame's
        detections with their class priors."""
        if self.stage is not None:
            conf = self.config.masking.conf
            return self.stage.inputs(features, got.objects, conf, depth_m, previous, got.lag)
        objects = Objects.empty(hw) if got.objects is None else got.objects
        objects = replace(objects, mobility=objects.priors(self.mobility))
        return FrameInputs(
            keypoints=features.keypoints, objects=objects, depth_m=depth_m,
            descriptors=features.descriptors, previous=previous, support=features.corners,
        )  # fmt: skip

    def _stillness(self, inputs: FrameInputs) -> FrameInputs:
        """The stillness test against the frames ``still_frames`` and half as many back."""
        earlier = compared_frames(self._history, self.config.masking.still_frames)
        still = None
        if earlier:
            still = find_still(inputs, earlier, inputs.objects.priors(self.mobility),
                               self._still_masks)  # fmt: skip
        masks = inputs.objects.masks
        self._still_masks = None if still is None or masks is None else masks[still]
        return inputs if still is None else replace(inputs, still=still)

    def _remember(self, features: OrbFeatures, depth_m: np.ndarray | None) -> None:
        """This frame as the next one's previous (with its depth where the camera is known:
        the motion layers and the PnP residual need it)."""
        config = self.config
        if config.camera is None:
            self._history.append(PreviousFrame(features))
        else:
            self._history.append(PreviousFrame(features, depth_m, config.camera,
                                               depth_residual=config.epipolar_depth))  # fmt: skip

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

    def _unmet(self, have: set[str], why: str) -> None:
        """Say once (log a warning), or with ``config.strict`` refuse, which settings of the
        masking cannot act for ``why`` (their levers need what ``have`` lacks)."""
        masking = self.config.masking
        lacking = unmet(masking.as_dict(), have)
        if not lacking:
            return
        what = ", ".join(f"{k} {_text(v)}" for k, v in masking.as_dict().items() if k in lacking)
        text = f"{why}: {what} cannot act"
        if "cut_behind_m" in lacking:  # the boxes nothing cuts: Eq. 4 at the papers' t_o
            text += (f"; Eq. 4 puts a box only in place of a seg mask covering at most "
                     f"{min(masking.t_o, T_O):g} of it (RGB-only masking, "
                     "docs/slam_defaults.md §6)")  # fmt: skip
        if self.config.strict:
            raise FrameError(f"{text} (strict: give what they need, or switch them off)")
        log.warning("%s", text)

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


def _text(v: Value) -> str:
    return v if isinstance(v, str) else f"{v:g}"


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
