"""How often the model runs in a frame loop: one type for the three ways (docs/tracking.md §6).

- ``ModelRate.every_n(N)``: inline, on frames 0, N, 2N, ... (``every_n(1)``: every frame);
- ``ModelRate.budget(B)``: inline, N chosen while running so that the mean ms per frame stays
  within B (:class:`~slimseg.dynamic.model_feed.ModelFeed`);
- ``ModelRate.own_thread()``: on a worker thread, the newest finished result used.

A rate other than every frame works only with the track stage (the tracks carry the masks
over the frames without a result); :class:`~slimseg.dynamic.chain_config.TrackPlan` checks
that.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from slimseg.errors import SlimsegError


@dataclass(frozen=True)
class ModelRate:
    """One of: every ``every`` frames, a ``budget_ms`` per frame, or its own ``thread``
    (build with :meth:`every_n`, :meth:`budget`, :meth:`own_thread` or :meth:`parse`)."""

    every: int = 1
    budget_ms: float = 0.0
    thread: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.every, bool) or not isinstance(self.every, int) or self.every < 1:
            raise SlimsegError(f"model rate: every {self.every!r} frames, expected 1 or more")
        if not (self.budget_ms >= 0 and math.isfinite(self.budget_ms)):
            raise SlimsegError(f"model rate: budget {self.budget_ms} ms, expected a number >= 0")
        ways = (self.every > 1) + (self.budget_ms > 0) + bool(self.thread)
        if ways > 1:
            raise SlimsegError(f"model rate {self!r}: give one of every N, a budget, a thread")

    @classmethod
    def every_n(cls, n: int) -> ModelRate:
        return cls(every=n)

    @classmethod
    def budget(cls, ms: float) -> ModelRate:
        if not ms > 0:
            raise SlimsegError(f"model rate: budget {ms} ms, expected a positive number")
        return cls(budget_ms=float(ms))

    @classmethod
    def own_thread(cls) -> ModelRate:
        return cls(thread=True)

    @classmethod
    def parse(cls, text: str) -> ModelRate:
        """``N`` | ``budget:MS`` | ``thread`` (``per-frame``: every frame)."""
        t = text.strip()
        try:
            if t in ("per-frame", "1"):
                return EVERY_FRAME
            if t == "thread":
                return cls.own_thread()
            if t.startswith("budget:"):
                return cls.budget(float(t.split(":", 1)[1]))
            return cls.every_n(int(t))
        except ValueError:
            raise SlimsegError(
                f"model rate {text!r}: expected N, budget:MS or thread (e.g. 3, budget:25)"
            ) from None

    @property
    def every_frame(self) -> bool:
        """The model runs inline on every frame (the per-frame chain)."""
        return self.every == 1 and self.budget_ms == 0 and not self.thread

    @property
    def fixed(self) -> bool:
        """A schedule known in advance (every N): the frames the model runs on do not depend
        on time (cached sweeps can replay it)."""
        return self.budget_ms == 0 and not self.thread

    @property
    def name(self) -> str:
        """Short label: ``per-frame``, ``every 3``, ``budget 25 ms``, ``own thread``."""
        if self.thread:
            return "own thread"
        if self.budget_ms > 0:
            return f"budget {self.budget_ms:g} ms"
        return "per-frame" if self.every == 1 else f"every {self.every}"

    def describe(self) -> str:
        if self.thread:
            return "model on its own thread (newest result, moved into the frame)"
        if self.budget_ms > 0:
            return f"model rate from a budget of {self.budget_ms:g} ms per frame"
        return "model on every frame" if self.every == 1 else f"model on every {self.every}"


EVERY_FRAME = ModelRate()
