"""When the model runs in a frame loop, and on which thread (docs/tracking.md §6).

One interface (:class:`ModelFeed`) for the three rates of
:class:`~slimseg.dynamic.model_rate.ModelRate`: each frame asks :meth:`ModelFeed.frame` for
detections and gets this frame's, an older frame's, or none (the track stage carries the masks
over frames without).

- **every N**: the model runs, on the loop's thread, on frames 0, N, 2N, ...
- **budget B**: as every N, with N chosen while running so that the mean time per frame
  (model share + everything else) stays within B ms: after each model frame
  ``N = ceil(model_ms / (B - other_ms))`` from running means, between 1 and :data:`MAX_EVERY`.
- **own thread**: the model runs on a worker thread as a runtime would run it. A frame is
  handed to the worker whenever it is idle; every frame is masked as it arrives with the
  newest finished result, which belongs to an older frame (its *lag* in frames) and is moved
  into the current frame (:meth:`~slimseg.dynamic.track_run.TrackedSequence.inputs`). The
  first frame waits for its own result (nothing can be masked before one exists).

A result of the worker is used at the first frame after it is done.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from slimseg.dynamic.model_rate import EVERY_FRAME, ModelRate
from slimseg.objects import Objects

MAX_EVERY = 10  # the budget never lets the model skip more frames than this
BUDGET_WARMUP = 2  # model frames measured before the budget picks N (the model runs on each)


class Feed(Protocol):
    """What the chain asks for its model results: a :class:`ModelFeed` (a schedule at a
    rate), or a caller's own (a benchmark's fixed lag)."""

    lags: list[int]
    model_runs: int
    model_s: float

    def frame(self, i: int, rgb: np.ndarray, stamp: float) -> FedDetections: ...

    def other_time(self, seconds: float) -> None: ...

    def close(self) -> None: ...


RunModel = Callable[[np.ndarray, float], Objects]
"""The model as the feed calls it: ``(rgb uint8 [H, W, 3], stamp) -> Objects``."""


@dataclass(frozen=True)
class FedDetections:
    """The model's output for one frame of the loop: ``objects`` (None: none this frame),
    ``index`` the frame it was computed on (``lag`` = current - index frames), ``seconds`` the
    loop's thread spent waiting for it (the whole model time when it ran inline)."""

    objects: Objects | None
    index: int = -1
    lag: int = 0
    seconds: float = 0.0


class ModelFeed:
    """The model's schedule for one sequence run (see the module docstring)."""

    def __init__(
        self,
        run: RunModel,
        rate: ModelRate = EVERY_FRAME,
    ) -> None:
        self.run = run
        self.rate = rate
        self.model_runs = 0
        self.model_s = 0.0
        """seconds of model runs (on whichever thread)"""
        self.lags: list[int] = []
        """per result used: frames between the frame it was computed on and the one it fed"""
        self._next = 0  # inline: the next frame the model runs on
        self._other_s: list[float] = []
        self._pool: ThreadPoolExecutor | None = None
        self._job: tuple[int, Future] | None = None  # (frame handed over, its run)

    # -- the loop's calls ---------------------------------------------------------------------

    def frame(self, i: int, rgb: np.ndarray, stamp: float) -> FedDetections:
        """Detections for frame ``i`` (0-based, in order)."""
        if self.rate.thread:
            return self._threaded(i, rgb, stamp)
        if i < self._next:
            return FedDetections(None)
        t0 = time.perf_counter()
        objects = self.run(rgb, stamp)
        dt = time.perf_counter() - t0
        self.model_runs += 1
        self.model_s += dt
        self.lags.append(0)
        self._next = i + self.gap()
        return FedDetections(objects, i, 0, dt)

    def other_time(self, seconds: float) -> None:
        """Record the loop's time for one frame outside the model (the budget's other share)."""
        self._other_s.append(seconds)

    def gap(self) -> int:
        """Frames from one inline model frame to the next."""
        budget_ms = self.rate.budget_ms
        if budget_ms <= 0:
            return self.rate.every
        if self.model_runs < BUDGET_WARMUP or not self._other_s:
            return 1
        model_ms = 1000 * self.model_s / self.model_runs
        other_ms = 1000 * float(np.mean(self._other_s[-30:]))
        room = budget_ms - other_ms
        if room <= 0:
            return MAX_EVERY
        return int(min(max(math.ceil(model_ms / room), 1), MAX_EVERY))

    def close(self) -> None:
        """Wait for a model run still in flight and stop the worker."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    # -- own thread ---------------------------------------------------------------------------

    def _timed(self, rgb: np.ndarray, stamp: float) -> tuple[Objects, float]:
        t0 = time.perf_counter()
        objects = self.run(rgb, stamp)
        return objects, time.perf_counter() - t0

    def _ready(self) -> bool:
        """The worker's job is done."""
        return self._job[1].done()

    def _threaded(self, i: int, rgb: np.ndarray, stamp: float) -> FedDetections:
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="slimseg-model")
        waited = 0.0
        got = None
        if self._job is None and i == 0:  # the first frame waits for its own result
            self._job = (i, self._pool.submit(self._timed, rgb, stamp))
            t0 = time.perf_counter()
            self._job[1].result()
            waited = time.perf_counter() - t0
        if self._job is not None and self._ready():
            index, future = self._job
            objects, seconds = future.result()  # a model error surfaces here, in the loop
            self._job = None
            self.model_runs += 1
            self.model_s += seconds
            self.lags.append(i - index)
            got = FedDetections(objects, index, i - index, waited)
        if self._job is None and i > 0:  # idle: it takes this frame (frame 0 is done)
            self._job = (i, self._pool.submit(self._timed, rgb.copy(), stamp))
        return got or FedDetections(None, seconds=waited)

    def describe(self) -> str:
        return self.rate.describe()
