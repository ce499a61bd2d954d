"""What one frame of the masking chain gives back (:class:`MaskedFrame`), with its timing by
stage (:class:`FrameTiming`, :data:`STAGES`) and the clock that takes it (:class:`StageClock`).
:class:`~slimseg.dynamic.frame_masker.FrameMasker` makes them; reports, the predictor's
tracking loop and the benchmarks read them."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.mobility import Decision
from slimseg.dynamic.pipeline import FrameResult
from slimseg.objects import Objects

STAGES = ("model", "features", "objects", "stillness", "mobility", "layers", "rules")
"""The chain's stages in the order :meth:`FrameMasker.step` runs them (docs/architecture.md,
"The masking chain")."""


@dataclass(frozen=True)
class FrameTiming:
    """Milliseconds of one frame by stage (:data:`STAGES`), on the caller's thread (``model``:
    the inline run, or waiting for the worker); ``latency``: from the call to the mask."""

    stages: dict[str, float]
    latency: float

    @property
    def model(self) -> float:
        return self.stages["model"]

    @property
    def features(self) -> float:
        """ORB features of the frame."""
        return self.stages["features"]

    @property
    def track(self) -> float:
        """The objects (the track stage, or the priors) and the stillness test."""
        return self.stages["objects"] + self.stages["stillness"]

    @property
    def logic(self) -> float:
        """The mobility decision, the motion layers and the mode's rules (Eq. 1/3/4)."""
        return self.stages["mobility"] + self.stages["layers"] + self.stages["rules"]

    @property
    def masking(self) -> float:
        """Everything but the model: ORB + track stage + the mode's logic."""
        return self.features + self.track + self.logic


@dataclass(frozen=True)
class MaskedFrame:
    """One frame's outcome: ``mask uint8 [H, W]`` (255 = dynamic, drop features there) and
    ``dynamic bool [N]`` per keypoint; ``lag``: a model result arrived this frame, computed
    that many frames ago (None: none arrived); the mode's ``result`` (Eq. 1's threshold,
    dropped objects, Eq. 4 decisions); ``inputs``: what the chain saw (the keypoints, the
    objects with their base mobility, depth, the previous frame) and ``decision``: the
    mobility the rules used: the trace a report scores other modes on."""

    index: int
    stamp: float
    mask: np.ndarray
    dynamic: np.ndarray
    lag: int | None
    timing: FrameTiming
    result: FrameResult
    inputs: FrameInputs
    decision: Decision

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


class StageClock:
    """Milliseconds per named stage of one frame (``with clock("name"): ...``)."""

    def __init__(self) -> None:
        self.start = time.perf_counter()
        self.ms: dict[str, float] = {}
        self._began: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        t0 = self._began[name] = time.perf_counter()
        yield
        self.ms[name] = 1000 * (time.perf_counter() - t0)

    def since(self, name: str) -> float:
        """Seconds from the start of stage ``name`` to now."""
        return time.perf_counter() - self._began[name]

    def total_ms(self) -> float:
        return 1000 * (time.perf_counter() - self.start)
