"""Where dynamic-keypoint recall is lost, and what coasted masks cost (docs/tracking.md §4).

Against a synthetic sequence's ground-truth instances (``annotations.json``), every missed
dynamic keypoint (on a moving instance, not flagged dynamic) is charged to its instance's
state in that frame:

- **dropout**: the output mask covers less than :data:`DROPOUT_COVER` of the instance: the
  detector (or the tracks) lost the walker in this frame; coasting can win these back;
- **partial**: the instance is covered, but not this keypoint (a coarse limb, an edge): only
  better masks win these back.

Runs of consecutive dropout frames per instance give the dropout-length histogram, which
bounds what a coasting horizon K can buy. Ghosts: false dynamic keypoints that lie only on
coasted (predicted) masks, overall and within :data:`AFTER_EXIT_FRAMES` frames after an
instance left the view.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from slimseg.detections import Prediction
from slimseg.dynamic.annotations import AnnotationInstances


@dataclass(frozen=True)
class FrameInstances:
    """A frame's ground-truth instances, decoded once for every tally of the frame: ``pred``
    (boxes, classes, names, ``masks bool [N, H, W]``), their ``moving bool [N]`` flags and
    ``ids int64 [N]`` track ids."""

    pred: Prediction
    moving: np.ndarray
    ids: np.ndarray

    @classmethod
    def of(cls, instances: AnnotationInstances, stamp: float) -> FrameInstances:
        """The instances of ``instances`` at ``stamp``."""
        return cls(instances.for_stamp(stamp), instances.moving(stamp),
                   instances.track_ids(stamp))  # fmt: skip


DROPOUT_COVER = 0.2  # an instance less covered than this is "missed entirely" in that frame
AFTER_EXIT_FRAMES = 10  # frames after an instance's last appearance that count as "after exit"


@dataclass
class RecallLoss:
    """Counts over a sequence; :meth:`add` once per frame in order."""

    missed: int = 0
    """missed dynamic keypoints (on a moving ground-truth instance)"""
    on_dropouts: int = 0
    on_partial: int = 0
    dropout_frames: int = 0
    instance_frames: int = 0
    """moving instance-frames, and how many of them were dropouts"""
    gaps: Counter = field(default_factory=Counter)
    """dropout run length (frames) → how many runs"""
    predicted_dynamic: int = 0
    ghosts: int = 0
    """false dynamic keypoints only on coasted masks"""
    ghosts_after_exit: int = 0
    _run: dict[int, int] = field(default_factory=dict)
    _last_seen: dict[int, int] = field(default_factory=dict)
    _frame: int = 0

    def add(
        self,
        frame: FrameInstances,
        keypoints: np.ndarray,
        dynamic: np.ndarray,
        truth: np.ndarray,
        region: np.ndarray,
        coasted_only: np.ndarray | None = None,
    ) -> None:
        """One frame: its ground-truth instances ``frame``, ``keypoints [N, 2]``, the
        output's ``dynamic [N]`` and ``truth [N]`` flags, the output ``region bool [H, W]``
        (the dynamic mask written), and ``coasted_only bool [H, W]`` (pixels covered by coasted
        masks and no detection)."""
        pred, moving, ids = frame.pred, frame.moving, frame.ids
        x = np.clip(np.round(keypoints[:, 0]).astype(int), 0, region.shape[1] - 1)
        y = np.clip(np.round(keypoints[:, 1]).astype(int), 0, region.shape[0] - 1)
        miss = truth & ~dynamic
        self.missed += int(miss.sum())
        seen = set()
        for k in np.flatnonzero(moving):
            m = pred.masks[k]
            area = int(m.sum())
            if area == 0:
                continue
            tid = int(ids[k])
            seen.add(tid)
            self._last_seen[tid] = self._frame
            cover = float((m & region).sum()) / area
            dropout = cover < DROPOUT_COVER
            self.instance_frames += 1
            self.dropout_frames += dropout
            on = miss & m[y, x]
            if dropout:
                self.on_dropouts += int(on.sum())
                self._run[tid] = self._run.get(tid, 0) + 1
            else:
                self.on_partial += int(on.sum())
                self._close(tid)
        for tid in [t for t in self._run if t not in seen]:
            self._close(tid)
        self.predicted_dynamic += int(dynamic.sum())
        if coasted_only is not None:
            ghost = dynamic & ~truth & coasted_only[y, x]
            self.ghosts += int(ghost.sum())
            recent = any(0 < self._frame - f <= AFTER_EXIT_FRAMES
                         for t, f in self._last_seen.items() if t not in seen)  # fmt: skip
            if recent:
                self.ghosts_after_exit += int(ghost.sum())
        self._frame += 1

    def _close(self, tid: int) -> None:
        n = self._run.pop(tid, 0)
        if n:
            self.gaps[n] += 1

    def finish(self) -> RecallLoss:
        """Close the dropout runs still open at the end of the sequence."""
        for tid in list(self._run):
            self._close(tid)
        return self

    def summary(self) -> dict[str, float | int | dict[int, int]]:
        """The figures docs/tracking.md reports (shares in %, NaN when undefined)."""

        def pct(a: int, b: int) -> float:
            return 100.0 * a / b if b else float("nan")

        lengths = sorted(self.gaps.elements())
        return {
            "missed_dynamic_keypoints": self.missed,
            "missed_on_dropouts_pct": pct(self.on_dropouts, self.missed),
            "missed_on_partial_pct": pct(self.on_partial, self.missed),
            "dropout_frames_pct": pct(self.dropout_frames, self.instance_frames),
            "dropout_runs": len(lengths),
            "dropout_median_frames": float(np.median(lengths)) if lengths else float("nan"),
            "dropout_runs_le3_pct": pct(sum(n <= 3 for n in lengths), len(lengths)),
            "dropout_histogram": dict(sorted(self.gaps.items())),
            "ghost_pct": pct(self.ghosts, self.predicted_dynamic),
            "ghosts_after_exit": self.ghosts_after_exit,
        }
