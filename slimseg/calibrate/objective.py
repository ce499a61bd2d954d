"""The calibration's measured objective: keypoint precision at a recall floor, per frame and
with the track stage, on every calibration sequence.

A candidate's masks are scored on the keypoints ORB finds (the ones a SLAM engine would
drop), against the sequences' ground-truth ``dynamic/`` masks: recall is the share of dynamic
keypoints masked (a missed walker is what wrecks a trajectory), precision the share of masked
keypoints that were dynamic (what a mask costs the static map). Each (sequence, condition)
scores ``precision - RECALL_WEIGHT * max(0, floor - recall)``; the objective is their mean,
so a candidate cannot buy precision on one sequence with a walker missed on another.

The model runs once per frame (:class:`~slimseg.sequence.detection_cache.DetectionCache`, at
the lowest score threshold any candidate or the track stage asks for); a candidate costs the
masking logic only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from slimseg.dynamic.chain_config import TRACK_OFF, TrackPlan
from slimseg.dynamic.masking_settings import MaskingSettings
from slimseg.dynamic.modes import Mode
from slimseg.dynamic.track_settings import DEFAULT_TRACK_PRESET, track_preset
from slimseg.sequence.detection_cache import DetectionCache, mask_with
from slimseg.sequence.sequence_report import ModeScore

#: Recall below which a candidate is penalised (the issue's target: >= 95 %).
RECALL_FLOOR = 0.95
#: Precision points one point of recall below the floor costs: a missed walker costs a SLAM
#: system far more than a few static keypoints dropped.
RECALL_WEIGHT = 5.0
#: The two conditions a candidate is scored under: the model on every frame, and the track
#: stage a robot runs (its shipped preset) carrying masks across frames.
CONDITIONS: dict[str, TrackPlan] = {
    "per_frame": TRACK_OFF,
    "track": TrackPlan(track_preset(DEFAULT_TRACK_PRESET)),
}


@dataclass(frozen=True)
class CellScore:
    """One (sequence, condition): keypoint ``precision`` and ``recall`` (NaN: no keypoint
    masked / no dynamic keypoint), the masking logic's ms per frame, and the mean shares of
    the frame masked and of the keypoints left static."""

    sequence: str
    condition: str
    precision: float
    recall: float
    logic_ms: float
    mask_share: float = 0.0
    static_share: float = 1.0

    def value(self, floor: float = RECALL_FLOOR) -> float:
        """``precision - RECALL_WEIGHT * shortfall``; a mask that drops nothing scores 0 on a
        sequence with walkers (all recall lost: heavily penalised)."""
        p = 0.0 if math.isnan(self.precision) else self.precision
        r = 1.0 if math.isnan(self.recall) else self.recall
        return p - RECALL_WEIGHT * max(0.0, floor - r)


@dataclass(frozen=True)
class Evaluation:
    """A candidate's scores: one :class:`CellScore` per (sequence, condition)."""

    settings: MaskingSettings
    cells: tuple[CellScore, ...] = field(default_factory=tuple)

    def value(self, floor: float = RECALL_FLOOR) -> float:
        """The objective: the mean of the cells' values (higher is better)."""
        return sum(c.value(floor) for c in self.cells) / max(len(self.cells), 1)

    def pooled(self, condition: str) -> tuple[float, float]:
        """``(precision, recall)`` over every sequence under ``condition`` (mean of cells)."""
        cells = [c for c in self.cells if c.condition == condition]
        p = [c.precision for c in cells if not math.isnan(c.precision)]
        r = [c.recall for c in cells if not math.isnan(c.recall)]
        mean = lambda v: sum(v) / len(v) if v else float("nan")  # noqa: E731
        return mean(p), mean(r)

    def shares(self, condition: str = "per_frame") -> tuple[float, float]:
        """Mean ``(mask share, static keypoint share)`` over the sequences under
        ``condition``: what the chain expects of this model under these settings."""
        cells = [c for c in self.cells if c.condition == condition] or list(self.cells)
        n = max(len(cells), 1)
        return sum(c.mask_share for c in cells) / n, sum(c.static_share for c in cells) / n

    def floor_met(self, floor: float = RECALL_FLOOR) -> bool:
        """Every cell's recall at or above ``floor``."""
        return all(math.isnan(c.recall) or c.recall >= floor for c in self.cells)


def conf_floor(lowest_conf: float) -> float:
    """The score threshold the detection cache must reach so that every candidate (conf down
    to ``lowest_conf``) and the track stage's second pass are answered from it."""
    return min(plan.floor(lowest_conf) for plan in CONDITIONS.values())


def evaluate(
    settings: MaskingSettings,
    caches: dict[str, DetectionCache],
    mode: Mode | str = Mode.FUSION,
) -> Evaluation:
    """Mask every cached sequence under ``settings`` in both :data:`CONDITIONS` and score the
    keypoints (nothing written)."""
    cells = []
    for name, cache in caches.items():
        for condition, plan in CONDITIONS.items():
            res = mask_with(cache, mode, settings, None, plan)
            s = res.score or ModeScore()
            cells.append(CellScore(name, condition, s.precision, s.recall, res.logic_ms,
                                   res.mask_share, res.static_share))  # fmt: skip
    return Evaluation(settings, tuple(cells))
