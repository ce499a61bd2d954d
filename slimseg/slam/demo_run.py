"""The SLAM stage of ``slimseg demo``: the trained model's masks in ORB-SLAM3, end to end.

Export the fused model (FP32 ONNX, as ``slimseg export`` does), render one synthetic walking
sequence from a seed the training images did not use, build a small vocabulary from its frames
(offline: no ``ORBvoc.txt`` download), then track the sequence with ORB-SLAM3 RGB-D ``runs``
times in each of three conditions — raw frames, the model's masks (``fusion`` mode with the
shipped ``slimseg`` masking settings) and the ground-truth masks — through slam-eval's session
code (:mod:`slimseg.slam.session`): the same masking chain, the same evo scores and the same
report files (``results.md``, ``results.csv``, ``runs.csv``, ``trajectories.png``) under the
stage's folder. :func:`slam_table` is what ``metrics.json`` stores; :func:`write_figure` draws
``slam.png``.

Layout under ``folder``::

    sequence/            the TUM-layout sequence (rgb/, depth/, dynamic/, groundtruth.txt, ...)
    vocab.txt            DBoW2 vocabulary built from the sequence's frames (non-official)
    sequence.json        what sequence/ and vocab.txt were made from (reused when equal)
    masks/ trajectories/ results.* runs.csv trajectories.png orbslam3_settings.yaml
"""

from __future__ import annotations

import importlib
import json
import logging
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from slimseg.dynamic.masking_settings import CALIBRATED, DEFAULT_PRESET
from slimseg.dynamic.modes import Mode
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import write_json

if TYPE_CHECKING:
    from slimseg.deploy.onnx_export import ExportReport

log = logging.getLogger(__name__)

MODE = Mode.FUSION.value  # slimseg dynamic's default mode
CONDITIONS = ("raw", MODE, "gt")  # slam-eval names, in table order
KEYS = {"raw": "raw", MODE: "slimseg", "gt": "gt_masks"}  # metrics.json keys
LABELS = {"raw": "raw frames", MODE: "slimseg masks", "gt": "ground-truth masks"}
# ORB-SLAM3 runs per condition: its run-to-run spread needs at least five for a median with a
# meaningful min-max (docs/slam_eval.md)
DEMO_RUNS = 5


@dataclass(frozen=True)
class DemoSlamSettings:
    """The sequence (``preset``, ``seed``, ``frames``, ``size`` W×H) and the tracking: ``runs``
    per condition, replay ``speed`` (realtime × speed), ``vocab`` (None: build one)."""

    preset: str = "walking_xyz"
    seed: int = 1
    frames: int = 100
    size: tuple[int, int] = (640, 480)
    runs: int = DEMO_RUNS
    speed: float = 0.33
    vocab: Path | None = None
    threads: int | None = None
    progress: bool = True

    def sequence_key(self) -> dict[str, object]:
        """What the rendered sequence depends on (``sequence.json``)."""
        return {"preset": self.preset, "seed": self.seed, "frames": self.frames,
                "size": list(self.size)}  # fmt: skip


@dataclass
class SlamOutcome:
    """What the stage produced: per-condition results and rows, and where the files are."""

    folder: Path
    sequence: Path
    vocabulary: str
    results: list = field(default_factory=list)
    """``ConditionResult`` per condition, in :data:`CONDITIONS` order"""
    rows: list[dict] = field(default_factory=list)
    """slam-eval summary rows (the last one the still-camera floor)"""
    floor: float = float("nan")
    seconds: dict[str, float] = field(default_factory=dict)
    masking: str = ""
    """the masking settings the model's masks were made with (its preset's name and values)"""


def slam_extra_missing() -> list[str]:
    """The packages of the ``[slam]`` extra (pyorbslam3, evo) that do not import (imported
    here, not at module load)."""
    missing = []
    for name in ("pyorbslam3", "evo"):
        try:
            importlib.import_module(name)
        except ImportError:
            missing.append(name)
    return missing


def export_fp32(weights: Path, out: Path, imgsz: int) -> ExportReport:
    """``weights`` → fused FP32 ONNX at ``out`` (+ sidecar), parity-checked like
    ``slimseg export``; returns its ``ExportReport``."""
    from slimseg.deploy.onnx_export import export_onnx
    from slimseg.models.checkpoint import load_weights

    model, info = load_weights(weights)
    return export_onnx(model, out, (imgsz, imgsz), info.names, info.mobility)


def prepare_sequence(folder: Path, s: DemoSlamSettings) -> tuple[Path, bool]:
    """Render the sequence into ``folder/sequence``, or reuse it when ``sequence.json`` says
    it was made with the same settings. Returns the folder and whether it was reused."""
    from slimseg.data.synth.presets import PRESETS
    from slimseg.data.synth.sequence import write_sequence

    if s.preset not in PRESETS:
        raise SlimsegError(f"--slam-preset {s.preset!r}: valid presets are {sorted(PRESETS)}")
    if s.frames < 10 or s.runs < 1:
        raise SlimsegError(f"--slam-frames {s.frames} / --slam-runs {s.runs}: need ≥ 10 / ≥ 1")
    seq, marker = folder / "sequence", folder / "sequence.json"
    key = s.sequence_key()
    if (
        marker.is_file()
        and json.loads(marker.read_text()) == key
        and (seq / "groundtruth.txt").is_file()
    ):
        return seq, True
    marker.unlink(missing_ok=True)
    (folder / "vocab.txt").unlink(missing_ok=True)  # built from the old frames
    if seq.is_dir():
        shutil.rmtree(seq)
    write_sequence(seq, s.seed, 0, s.frames, s.size, preset=s.preset)
    write_json(marker, key)
    return seq, False


def prepare_vocabulary(folder: Path, seq: Path, s: DemoSlamSettings) -> tuple[Path, bool]:
    """``s.vocab`` if given, else ``folder/vocab.txt`` (built from the sequence's frames by
    :func:`~slimseg.slam.vocab.small_vocabulary` when absent). Returns it and whether it was
    built now."""
    if s.vocab is not None:
        return s.vocab, False
    vocab = folder / "vocab.txt"
    if vocab.is_file():
        return vocab, False
    from slimseg.slam.vocab import small_vocabulary

    small_vocabulary(sorted((seq / "rgb").glob("*.png")), vocab, seed=s.seed)
    return vocab, True


def evaluate(
    onnx: Path, seq_dir: Path, vocab: Path, folder: Path, s: DemoSlamSettings,
    say: Callable[[str], None],
) -> SlamOutcome:  # fmt: skip
    """Masks and ORB-SLAM3 runs of the three conditions, scored and reported as slam-eval
    does (its files land in ``folder``)."""
    from slimseg.data.tum import TumSequence
    from slimseg.deploy.calibrated import is_calibrated, model_masking, read_model_metadata
    from slimseg.slam import session
    from slimseg.slam.condition_runs import evaluate_condition
    from slimseg.slam.conditions import Condition
    from slimseg.slam.metrics import still_floor
    from slimseg.slam.report import RunInfo, write_report

    meta = read_model_metadata(onnx)
    masking, note = model_masking(meta, onnx)
    if note is not None:
        say(f"note: {note}")
    name = CALIBRATED if is_calibrated(meta) else DEFAULT_PRESET
    with TumSequence(seq_dir) as seq:
        plan = session.Plan(
            sequence=seq, names=list(CONDITIONS), model=str(onnx), runs=s.runs, vocab=vocab,
            masking=masking, speed=s.speed, threads=s.threads, progress=s.progress,
        )  # fmt: skip
        label = session.check_engine(plan.engine, vocab)
        session.clean(folder, None)
        gt = session.ground_truth(seq)
        t0 = time.perf_counter()
        masked = session.mask_conditions(plan, folder, say)
        t1 = time.perf_counter()
        raw = Condition("raw", "raw", note="the sequence's frames")
        conds = [raw, masked[MODE], masked["gt"]]
        cfg = session.engine_settings(plan, seq, folder)
        results = []
        for cond in conds:
            res = evaluate_condition(seq, cond, gt, cfg, folder / "trajectories")
            ates = ", ".join(f"{r.score.ate_rmse:.3f}" if r.score else "-" for r in res.runs)
            log.info("%s: ATE of %d runs %s m", cond.name, len(res.runs), ates)
            results.append(res)
        floor = still_floor(session.gt_at_frames(gt, seq))
        info = RunInfo(
            sequence=seq.root, frames=len(seq), engine=plan.engine, vocabulary=label,
            intrinsics=seq.camera_source, synthetic=True, runs=s.runs,
        )  # fmt: skip
        rows = write_report(folder, info, results, floor)
        seconds = {"masks": t1 - t0, "orbslam3": time.perf_counter() - t1}
        used = f"{name} preset {masking.as_dict()}"
        return SlamOutcome(folder, seq_dir, label, results, rows, floor, seconds, used)


def _num(v: object) -> float | None:
    return None if v is None or not np.isfinite(float(v)) else round(float(v), 5)


def slam_table(outcome: SlamOutcome, s: DemoSlamSettings) -> dict[str, object]:
    """The ``slam`` entry of ``metrics.json``: the setup, then per condition the ATE median,
    min and max (m) over the scored runs, every run's ATE, the median RPE (per second) and
    the run counts; ``None`` where nothing scored."""
    conditions = {}
    for name, res, row in zip(CONDITIONS, outcome.results, outcome.rows[:-1], strict=True):
        conditions[KEYS[name]] = {
            "label": LABELS[name],
            "ate_median_m": _num(row["ate_rmse"]),
            "ate_min_m": _num(row["ate_min"]),
            "ate_max_m": _num(row["ate_max"]),
            "ate_runs_m": [_num(r.score.ate_rmse) if r.score else None for r in res.runs],
            "rpe_trans_m_per_s": _num(row["rpe_trans_s"]),
            "rpe_rot_deg_per_s": _num(row["rpe_rot_s"]),
            "runs": row["runs"],
            "scored_runs": row["scored_runs"],
            "lost_frames_median": row["lost_median"],
            "status": row["status"],
            "note": row["note"],
        }
    return {
        "engine": "orbslam3 (RGB-D)",
        "sequence": {**s.sequence_key(), "path": str(outcome.sequence)},
        "masking": f"{MODE} mode, {outcome.masking}",
        "vocabulary": outcome.vocabulary,
        "runs_per_condition": s.runs,
        "replay_speed": s.speed,
        "still_camera_ate_m": _num(outcome.floor),
        "conditions": conditions,
        "report": str(outcome.folder / "results.md"),
    }


def write_figure(outcome: SlamOutcome, path: Path, s: DemoSlamSettings, model: str) -> Path:
    """``slam.png``: every scored run's top view, aligned to the ground truth as for the ATE,
    and the ATE bars (:func:`slimseg.slam.demo_plot.plot_demo_slam`)."""
    from slimseg.data.tum import read_trajectory
    from slimseg.slam.demo_plot import PlotCondition, plot_demo_slam
    from slimseg.slam.metrics import aligned_positions

    gt = read_trajectory(outcome.sequence / "groundtruth.txt")
    conds = []
    for name, res in zip(CONDITIONS, outcome.results, strict=True):
        scored = [r for r in res.runs if r.score is not None and r.trajectory is not None]
        xyz = [aligned_positions(gt, read_trajectory(r.trajectory)) for r in scored]
        ates = [r.score.ate_rmse for r in scored]
        conds.append(PlotCondition(LABELS[name], xyz, ates, len(res.runs)))
    w, h = s.size
    title = (
        f"ORB-SLAM3 RGB-D on the synthetic {s.preset} sequence (seed {s.seed}, {s.frames} "
        f"frames, {w}×{h}), {s.runs} runs per condition\nslimseg masks: {model} ONNX, {MODE} "
        f"mode, {outcome.masking.split(' ')[0]} masking preset; vocabulary built from the sequence "
        "(non-official)"
    )
    return plot_demo_slam(path, gt[:, 1:4], conds, title, floor=outcome.floor)
