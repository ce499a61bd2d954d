"""Where dynamic-keypoint precision is lost: what the false dynamic keypoints lie on.

Against a synthetic sequence's ground-truth instances (``annotations.json``), every keypoint the
chain flags dynamic that is static in ``dynamic/`` is charged to the static instance it lies on
(by class: a person standing still, a parked chair), or to the background (the room: wall,
floor, furniture no instance covers). The split says which lever can win precision back: a
standing person masked with the walkers is the stillness test's (``still_frames``); background
under a mask is the mask's fit (``dilation_px``, the depth cut, Eq. 4's box).

On held-out walking_xyz s131 with the demo's AMD model and the shipped preset, a person standing
while walkers pass in front of them holds most of the false dynamic pixels; restricting that
run's masks to the walkers (precision near 100 %, recall unchanged) brings ORB-SLAM3's ATE from
9x the ground-truth masks' to theirs (docs/calibrate.md, round 4).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from slimseg.dynamic.threshold import inside
from slimseg.sequence.recall_loss import FrameInstances

#: What a false dynamic keypoint on no static instance is charged to.
BACKGROUND = "background"


@dataclass
class PrecisionLoss:
    """Counts over a sequence; :meth:`add` once per frame."""

    false_dynamic: int = 0
    """keypoints flagged dynamic that ``dynamic/`` says are static"""
    on: Counter = field(default_factory=Counter)
    """class name of the static instance they lie on (or :data:`BACKGROUND`) → how many"""

    def add(
        self,
        frame: FrameInstances,
        keypoints: np.ndarray,
        dynamic: np.ndarray,
        truth: np.ndarray,
    ) -> None:
        """One frame: its ground-truth instances ``frame``, ``keypoints float [N, 2]`` (x, y)
        px, the output's ``dynamic bool [N]`` and the ground truth's ``truth bool [N]``."""
        false = np.flatnonzero(np.asarray(dynamic, bool) & ~np.asarray(truth, bool))
        if not len(false):
            return
        self.false_dynamic += len(false)
        left = np.ones(len(false), bool)
        if frame.pred.masks is not None:
            static = np.flatnonzero(~np.asarray(frame.moving, bool))
            for k, on in zip(static, inside(keypoints[false], frame.pred.masks[static]),
                             strict=True):  # fmt: skip
                hit = left & on
                if hit.any():
                    self.on[frame.pred.names[k]] += int(hit.sum())
                    left &= ~hit
        if left.any():
            self.on[BACKGROUND] += int(left.sum())

    def summary(self) -> dict[str, float | int]:
        """``{"false_dynamic_keypoints": n, "<class or background>_pct": share %, ...}``,
        largest share first."""
        out: dict[str, float | int] = {"false_dynamic_keypoints": self.false_dynamic}
        for name, n in self.on.most_common():
            out[f"{name}_pct"] = 100.0 * n / self.false_dynamic
        return out

    def describe(self) -> str:
        """One line: ``N false dynamic keypoints: 61.2 % on static person, 30.1 % on
        background, ...`` (static instances named by class)."""
        if not self.false_dynamic:
            return "no false dynamic keypoints"
        parts = [
            f"{100.0 * n / self.false_dynamic:.1f} % on "
            f"{name if name == BACKGROUND else 'static ' + name}"
            for name, n in self.on.most_common()
        ]
        return f"{self.false_dynamic} false dynamic keypoints: {', '.join(parts)}"
