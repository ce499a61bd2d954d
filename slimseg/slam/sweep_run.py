"""Run a masking-settings sweep: per sequence, detections once, then every setting's masks,
each tracked ``runs`` times beside the raw and ground-truth-mask references.

Output layout under ``out``::

    sweep.csv  sweep.md  sweep.png
    <sequence>/orbslam3_settings.yaml  <sequence>/runs.csv
    <sequence>/masks/<setting>/<ts>.png   <sequence>/trajectories/<condition>/run<k>.txt

A setting whose masks are identical, frame for frame, to an earlier setting's is not tracked
again: it shares that setting's runs (``same_as``), so a flat stretch of a curve costs nothing
and shows as exactly flat instead of as ORB-SLAM3's run-to-run noise.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from slimseg.data.tum import TumSequence
from slimseg.dynamic.annotations import Dropout
from slimseg.dynamic.chain_config import TRACK_OFF, TrackPlan
from slimseg.dynamic.masking_settings import DEFAULT, MaskingSettings
from slimseg.dynamic.modes import KEYPOINTS
from slimseg.errors import SlimsegError
from slimseg.sequence.detection_cache import SettingMasks, build_cache, mask_with
from slimseg.slam.condition_runs import ConditionResult, evaluate_condition
from slimseg.slam.conditions import Condition
from slimseg.slam.metrics import still_floor
from slimseg.slam.report import csv_text, run_rows
from slimseg.slam.session import (
    check_engine,
    clean,
    engine_settings,
    ground_truth,
    gt_at_frames,
    make_predictor,
)
from slimseg.slam.sweep import SweepPoint, check_mode, sweep_points
from slimseg.utils.atomic import add_to_manifest, write_text
from slimseg.utils.outputs import claim_folder

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SweepPlan:
    """What to sweep (the CLI's options, validated): ``spec`` key → values, ``how`` oneway |
    grid, around ``base``; one masking ``mode``; the model (or ground-truth instances)."""

    sequences: list[TumSequence]
    mode: str
    spec: dict[str, tuple]
    how: str = "oneway"
    base: MaskingSettings = DEFAULT
    model: str | None = None
    gt_instances: bool = False
    engine: str = "orbslam3"
    runs: int = 3
    vocab: Path | None = None
    keypoints: int = KEYPOINTS
    features: int = KEYPOINTS
    realtime: bool = True
    speed: float = 1.0
    threads: int | None = None
    progress: bool = True
    track: TrackPlan = TRACK_OFF
    """the track stage every setting runs with (off: every frame judged alone)"""
    dropout: Dropout | None = None
    """ground-truth instances only: simulated missed detections"""


@dataclass
class SequenceSweep:
    """One sequence's outcome: references (``raw``, ``gt``: None where absent), every point's
    tracking ``results`` and ``masks`` (keyed by label), the model time and the still floor."""

    label: str
    sequence: TumSequence
    points: list[SweepPoint]
    vocabulary: str
    raw: ConditionResult | None = None
    gt: ConditionResult | None = None
    results: dict[str, ConditionResult] = field(default_factory=dict)
    masks: dict[str, SettingMasks] = field(default_factory=dict)
    same_as: dict[str, str] = field(default_factory=dict)
    """label → the earlier label whose identical masks' runs it shares"""
    model_ms: float = 0.0
    floor: float = float("nan")
    gt_dilation_px: int = 0


def sequence_labels(sequences: list[TumSequence]) -> list[str]:
    """Short unique names: each folder's name, with parents prepended (``a_b``) until unique."""
    parts = [list(s.root.absolute().parts) for s in sequences]
    depth = 1
    while True:
        labels = ["_".join(p[-depth:]) for p in parts]
        if len(set(labels)) == len(labels) or depth >= max(len(p) for p in parts):
            return labels
        depth += 1


def _slug(label: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in label)


SWEEP_TABLES = ("sweep.md", "sweep.csv", "sweep.png")  # written beside the sequence folders


def claim_sweep_out(plan: SweepPlan, out: Path) -> None:
    """Refuse an ``out`` holding anything slimseg did not write (``SlimsegError``), then list
    what the sweep will write there (one folder per sequence, the tables) in its manifest
    (:mod:`slimseg.utils.outputs`), before any of it is written."""
    folders = [_slug(label) for label in sequence_labels(plan.sequences)]
    claim_folder(out, "--out", own=[*folders, *SWEEP_TABLES])
    out.mkdir(parents=True, exist_ok=True)
    add_to_manifest(out, "slam-eval --sweep", [*folders, *SWEEP_TABLES])


def run_sweep(plan: SweepPlan, out: Path, say: Callable[[str], None]) -> list[SequenceSweep]:
    """Everything after option parsing; returns one :class:`SequenceSweep` per sequence."""
    check_mode(plan.spec, plan.mode, plan.gt_instances)
    vocab_label = check_engine(plan.engine, plan.vocab)
    points = sweep_points(plan.base, plan.spec, plan.how, ignore_conf=plan.gt_instances,
                          track=plan.track.settings)  # fmt: skip
    floor_conf = plan.track.floor(min(p.settings.conf for p in points))
    say(
        f"sweep: {len(points)} settings x {plan.runs if plan.engine == 'orbslam3' else 1} runs "
        f"on {len(plan.sequences)} sequence(s); detections once per frame at conf {floor_conf}"
    )
    predictor = None
    sweeps = []
    for label, seq in zip(sequence_labels(plan.sequences), plan.sequences, strict=True):
        if predictor is None or plan.gt_instances:
            predictor = make_predictor(plan.model, plan.gt_instances, seq.root, plan.threads,
                                       plan.dropout)  # fmt: skip
        sweeps.append(_one_sequence(plan, seq, label, points, predictor, vocab_label, out, say))
    return sweeps


def _one_sequence(
    plan: SweepPlan,
    seq: TumSequence,
    label: str,
    points: list[SweepPoint],
    predictor: object,
    vocab_label: str,
    out: Path,
    say: Callable[[str], None],
) -> SequenceSweep:
    folder = out / _slug(label)
    gt_path = seq.root / "groundtruth.txt"
    if not gt_path.is_file():
        raise SlimsegError(f"{gt_path} is missing: a trajectory cannot be scored without it")
    gt = ground_truth(seq)
    clean(folder, None)
    cfg = engine_settings(plan, seq, folder)
    floor = still_floor(gt_at_frames(gt, seq))
    result = SequenceSweep(label, seq, points, vocab_label, floor=floor)
    tracks = folder / "trajectories"

    def track(cond: Condition) -> ConditionResult:
        res = evaluate_condition(seq, cond, gt, cfg, tracks)
        s = res.summary()
        ate = "-" if s["ate_rmse"] is None else f"{s['ate_rmse']:.4f} m"
        say(f"{label} {cond.name}: ATE {ate} ({s['scored_runs']}/{s['runs']} runs), {s['status']}")
        return res

    floor_conf = plan.track.floor(min(p.settings.conf for p in points))
    cache = build_cache(predictor, seq, floor_conf, plan.keypoints, plan.progress)
    result.model_ms = cache.model_ms
    say(f"{label}: {len(cache.frames)} frames, model {cache.model_ms:.1f} ms/frame "
        f"({cache.calls} calls)")  # fmt: skip
    result.raw = track(Condition("raw", "raw", note="the sequence's frames"))
    if (seq.root / "dynamic").is_dir():
        result.gt_dilation_px = d = plan.base.dilation_px
        result.gt = track(Condition("gt", "masked", masks=seq.root / "dynamic", dilation_px=d,
                                    note=f"ground-truth dynamic/, dilated {d} px"))  # fmt: skip
    by_digest: dict[str, str] = {}
    for p in points:
        where = folder / "masks" / _slug(p.label)
        stage = plan.track if p.track is None else TrackPlan(p.track, plan.track.rate)
        sm = mask_with(cache, plan.mode, p.settings, where, stage)
        result.masks[p.label] = sm
        ms = cache.model_ms * sm.model_share + sm.logic_ms
        cond = Condition(p.label, "masked", masks=where, masking_ms=ms,
                         note=f"--mode {plan.mode}, {p.settings.as_dict()}")  # fmt: skip
        first = by_digest.setdefault(sm.digest, p.label)
        if first != p.label:
            result.same_as[p.label] = first
            result.results[p.label] = ConditionResult(cond, result.results[first].runs)
            say(f"{label} {p.label}: masks identical to {first}'s, its runs shared")
            continue
        result.results[p.label] = track(cond)
    tracked = [r for k, r in result.results.items() if k not in result.same_as]
    runs = run_rows([r for r in (result.raw, result.gt) if r] + tracked)
    if runs:
        write_text(folder / "runs.csv", csv_text(runs, list(runs[0])))
    return result
