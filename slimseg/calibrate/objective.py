"""The calibration's measured objective: keypoint precision at a recall floor, per frame and
with the track stage, on every calibration sequence.

A candidate's masks are scored on the keypoints ORB finds (the ones a SLAM engine would
drop), against the sequences' ground-truth ``dynamic/`` masks: recall is the share of dynamic
keypoints masked (a missed walker is what wrecks a trajectory), precision the share of masked
keypoints that were dynamic (what a mask costs the static map), walker recall the share of
walker-frames (ground-truth regions, :class:`~slimseg.sequence.sequence_report.ModeScore`)
not lost entirely. Each (sequence, condition) falls short of the floor by
``max(0, floor - recall, floor - walker recall)``; the objective is the cells' mean precision
minus ``RECALL_WEIGHT`` times the *sum* of their shortfalls, so a candidate cannot buy
precision on every sequence with a walker missed on one (a mean of per-cell penalties would
divide that walker's cost by the number of cells: the first calibrations did exactly that).

The floor the search holds is the target plus :data:`RECALL_MARGIN`: settings are chosen on a
few short sequences and judged on others, where the model scores its walkers lower (settings
chosen at the target's edge lost 5-30 recall points on held-out rotating-camera sequences,
docs/calibrate.md).

A candidate is chosen by what it *earns* over the shipped preset, not by its objective alone
(:meth:`Evaluation.earned`): the objective is a mean over cells, so it is a mean of per-cell
contributions, and a candidate's paired gains over the shipped preset cell by cell give a
mean and a standard error. What it earns is the mean less :data:`EARN_SE` standard errors: a
candidate that gains on one sequence and loses on another earns less than one that gains a
little on each, and the shipped preset earns 0. On four 60-frame sequences, settings chosen
for a gain on some cells paid for it on held-out sequences (a 12-px dilation's precision, an
Eq. 1 step that gave walkers up under a rotating camera; docs/calibrate.md). Among the
candidates that earn something, the one-standard-error rule prefers the fewest knobs moved
(:func:`slimseg.calibrate.search.preferred`).

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

#: The keypoint recall a model's masks must keep on sequences it was not calibrated on.
RECALL_TARGET = 0.95
#: Recall kept above the target on the calibration sequences, for the ones it is not.
RECALL_MARGIN = 0.02
#: Recall below which a candidate is penalised.
RECALL_FLOOR = RECALL_TARGET + RECALL_MARGIN
#: Precision points one point of recall below the floor costs: a missed walker costs a SLAM
#: system far more than a few static keypoints dropped.
RECALL_WEIGHT = 5.0
#: Standard errors of the per-cell gains a candidate's mean gain over the shipped preset must
#: clear before it counts (one: a gain the cells agree on, not one a single cell carries).
EARN_SE = 1.0
#: The two conditions a candidate is scored under: the model on every frame, and the track
#: stage a robot runs (its shipped preset) carrying masks across frames.
CONDITIONS: dict[str, TrackPlan] = {
    "per_frame": TRACK_OFF,
    "track": TrackPlan(track_preset(DEFAULT_TRACK_PRESET)),
}


@dataclass(frozen=True)
class CellScore:
    """One (sequence, condition): keypoint ``precision`` and ``recall`` (NaN: no keypoint
    masked / no dynamic keypoint), the masking logic's ms per frame, the mean shares of the
    frame masked and of the keypoints left static, and the walker-frames' recall (NaN: none
    counted)."""

    sequence: str
    condition: str
    precision: float
    recall: float
    logic_ms: float
    mask_share: float = 0.0
    static_share: float = 1.0
    walker_recall: float = float("nan")

    @property
    def kept_precision(self) -> float:
        """Precision, 0 where nothing was masked."""
        return 0.0 if math.isnan(self.precision) else self.precision

    def shortfall(self, floor: float = RECALL_FLOOR) -> float:
        """How far the lower of keypoint and walker recall falls below ``floor`` (0: met; a
        mask that drops nothing on a sequence with walkers falls short by the whole floor)."""
        r = [v for v in (self.recall, self.walker_recall) if not math.isnan(v)]
        return max(0.0, floor - min(r, default=1.0))

    def value(self, floor: float = RECALL_FLOOR) -> float:
        """This cell alone: ``precision - RECALL_WEIGHT * shortfall``."""
        return self.kept_precision - RECALL_WEIGHT * self.shortfall(floor)


@dataclass(frozen=True)
class Evaluation:
    """A candidate's scores: one :class:`CellScore` per (sequence, condition)."""

    settings: MaskingSettings
    cells: tuple[CellScore, ...] = field(default_factory=tuple)

    def value(self, floor: float = RECALL_FLOOR) -> float:
        """The objective (higher is better): the cells' mean precision minus
        ``RECALL_WEIGHT`` times the sum of their shortfalls."""
        precision = sum(c.kept_precision for c in self.cells) / max(len(self.cells), 1)
        return precision - RECALL_WEIGHT * sum(c.shortfall(floor) for c in self.cells)

    def contributions(self, floor: float = RECALL_FLOOR) -> tuple[float, ...]:
        """Each cell's share of :meth:`value` times the number of cells (their mean is the
        objective): ``precision - RECALL_WEIGHT * n_cells * shortfall``."""
        n = len(self.cells)
        return tuple(c.kept_precision - RECALL_WEIGHT * n * c.shortfall(floor)
                     for c in self.cells)  # fmt: skip

    def gain(self, base: Evaluation, floor: float = RECALL_FLOOR) -> tuple[float, float]:
        """``(mean, standard error)`` of the paired per-cell gains in :meth:`contributions`
        over ``base`` (scored on the same cells, in the same order; one cell: SE 0)."""
        if [(c.sequence, c.condition) for c in self.cells] != [
            (c.sequence, c.condition) for c in base.cells
        ]:
            raise ValueError("gain(): the two evaluations were scored on different cells")
        gains = [a - b for a, b in zip(self.contributions(floor), base.contributions(floor),
                                       strict=True)]  # fmt: skip
        n = len(gains)
        if n == 0:
            return 0.0, 0.0
        mean = sum(gains) / n
        if n == 1:
            return mean, 0.0
        return mean, math.sqrt(sum((g - mean) ** 2 for g in gains) / (n - 1) / n)

    def earned(self, base: Evaluation, floor: float = RECALL_FLOOR) -> float:
        """What these settings earn over ``base``: the mean paired per-cell gain less
        :data:`EARN_SE` standard errors (:meth:`gain`; 0 against itself)."""
        mean, se = self.gain(base, floor)
        return mean - EARN_SE * se

    def pooled(self, condition: str) -> tuple[float, float]:
        """``(precision, recall)`` over every sequence under ``condition`` (mean of cells)."""
        cells = [c for c in self.cells if c.condition == condition]
        p = [c.precision for c in cells if not math.isnan(c.precision)]
        r = [c.recall for c in cells if not math.isnan(c.recall)]
        mean = lambda v: sum(v) / len(v) if v else float("nan")  # noqa: E731
        return mean(p), mean(r)

    def walkers(self, condition: str) -> float:
        """Mean walker-frame recall over the sequences under ``condition`` (NaN: none)."""
        r = [c.walker_recall for c in self.cells
             if c.condition == condition and not math.isnan(c.walker_recall)]  # fmt: skip
        return sum(r) / len(r) if r else float("nan")

    def shares(self, condition: str = "per_frame") -> tuple[float, float]:
        """Mean ``(mask share, static keypoint share)`` over the sequences under
        ``condition``: what the chain expects of this model under these settings."""
        cells = [c for c in self.cells if c.condition == condition] or list(self.cells)
        n = max(len(cells), 1)
        return sum(c.mask_share for c in cells) / n, sum(c.static_share for c in cells) / n

    def floor_met(self, floor: float = RECALL_FLOOR) -> bool:
        """Every cell's keypoint and walker recall at or above ``floor``."""
        return all(c.shortfall(floor) == 0.0 for c in self.cells)


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
                                   res.mask_share, res.static_share,
                                   s.walker_recall))  # fmt: skip
    return Evaluation(settings, tuple(cells))
