"""One slam-eval session: make every condition's masks or frames, track, score, report.

Output layout under ``out``::

    masks/<mode>/masks/<ts>.png   the mode's dynamic masks (as ``slimseg dynamic`` writes them)
    restore/<condition>/restored/{rgb,depth}/<ts>.png   restored frames (``--restore``)
    trajectories/<condition>/run<k>.txt   TUM trajectory of each run (+ orbslam3.log)
    orbslam3_settings.yaml   results.csv  runs.csv  results.md  trajectories.png
"""

from __future__ import annotations

import logging
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from slimseg.data.frame_source import FrameSource
from slimseg.data.images import decode_file
from slimseg.data.tum import MAX_DT, mask_name, read_trajectory
from slimseg.dynamic.annotations import Dropout
from slimseg.dynamic.chain_config import TRACK_OFF, ChainConfig, TrackPlan
from slimseg.dynamic.masking_settings import DEFAULT, MaskingSettings, preset_name
from slimseg.dynamic.modes import KEYPOINTS
from slimseg.errors import SlimsegError
from slimseg.slam.condition_runs import ConditionResult, EngineRunConfig, evaluate_condition
from slimseg.slam.conditions import (
    Condition,
    check_masks,
    oracle_paths,
    restored_paths,
)
from slimseg.slam.diagnostic import DIAGNOSTIC, NOTES
from slimseg.slam.metrics import still_floor
from slimseg.slam.orbslam3_config import OrbSlam3Config, write_settings
from slimseg.slam.report import RunInfo, write_report

log = logging.getLogger(__name__)

OWNED = ("masks", "restore", "trajectories")  # folders a new session replaces


@dataclass(frozen=True)
class Plan:
    """What to evaluate (the CLI's options, validated)."""

    sequence: FrameSource
    names: list[str]
    groundtruth: Callable[[], np.ndarray] | None = None
    """reads the true poses ``[K, 8]`` (TUM rows; ``--groundtruth`` / ``--pose-topic``), called
    where the folder's ``groundtruth.txt`` would be read; None: that file"""
    model: str | None = None
    gt_instances: bool = False
    masks: Path | None = None
    restore: tuple[str, ...] = ()
    """masked condition names (``--modes`` spelling) whose restored frames are evaluated"""
    engine: str = "orbslam3"
    runs: int = 3
    vocab: Path | None = None
    masking: MaskingSettings = DEFAULT
    """score threshold, dilation and Eq. 1/3/4 parameters of the mask modes; its dilation also
    widens the ground-truth masks"""
    keypoints: int = KEYPOINTS
    track: TrackPlan = TRACK_OFF
    """the track stage of the mask modes (off: every frame judged alone)"""
    dropout: Dropout | None = None
    """ground-truth instances only: simulated missed detections"""
    features: int = KEYPOINTS
    realtime: bool = True
    speed: float = 1.0
    threads: int | None = None
    progress: bool = True
    rerun: Path | None = None
    """a Rerun recording of the trajectories to write (``--rerun``), None: none"""


def gt_at_frames(gt: np.ndarray, seq: FrameSource, max_dt: float = MAX_DT) -> np.ndarray:
    """Ground-truth rows ``[K, 8]`` nearest to each frame's RGB stamp (within ``max_dt``)."""
    stamps = np.array([t for (t, _), _ in seq.frames])
    j = np.clip(np.searchsorted(gt[:, 0], stamps), 1, len(gt) - 1)
    j = np.where(np.abs(gt[j - 1, 0] - stamps) < np.abs(gt[j, 0] - stamps), j - 1, j)
    return gt[j[np.abs(gt[j, 0] - stamps) <= max_dt]]


def check_engine(engine: str, vocab: Path | None) -> str:
    """Fail fast on a missing extra or vocabulary; returns the vocabulary label."""
    from slimseg.slam.metrics import _evo

    _evo()
    if engine == "dense":
        return "none (dense engine)"
    from slimseg.slam.engines import import_pyorbslam3
    from slimseg.slam.vocab import check_vocabulary

    import_pyorbslam3()
    if vocab is None:
        raise SlimsegError(
            "--engine orbslam3 needs --vocab: the official ORBvoc.txt, or build one offline "
            "with slimseg slam vocab --images 'SEQ/rgb/*.png' --out voc.txt"
        )
    return check_vocabulary(vocab).label


def mask_conditions(plan: Plan, out: Path, say: Callable[[str], None]) -> dict[str, Condition]:
    """The masked conditions by requested name, in ``plan.names`` order, their masks made or
    checked (``gt`` is left out where the sequence has no ``dynamic/``)."""
    seq = plan.sequence
    conds: dict[str, Condition] = {}
    predictor = None
    for name in plan.names:
        if name == "gt":
            folder = seq.root / "dynamic"
            if not folder.is_dir():
                say(f"gt: skipped, {folder} does not exist (real sequences have none)")
                continue
            check_masks(seq, folder)
            d = plan.masking.dilation_px
            conds[name] = Condition("gt", "masked", masks=folder, dilation_px=d,
                                    note=f"ground-truth dynamic/, dilated {d} px")  # fmt: skip
        elif name == "masks":
            folder = _read_masks(plan)
            check_masks(seq, folder)
            conds[name] = Condition(f"masks ({plan.masks.name})", "masked", masks=folder,
                                    note=f"read from {folder}")  # fmt: skip
        elif name in DIAGNOSTIC:
            truth = seq.root / "dynamic"
            if not truth.is_dir():
                say(f"{name}: skipped, {truth} does not exist (it combines the masks with it)")
                continue
            folder = _read_masks(plan)
            check_masks(seq, folder)
            check_masks(seq, truth)
            how = DIAGNOSTIC[name]
            conds[name] = Condition(
                f"masks ({plan.masks.name}) {how} gt", "masked", masks=folder, truth=truth,
                combine=how, note=NOTES[how],
            )  # fmt: skip
        elif name not in ("raw", "oracle"):
            if predictor is None:
                predictor = make_predictor(plan.model, plan.gt_instances, seq.root, plan.threads,
                                           plan.dropout)  # fmt: skip
            conds[name] = _mode_condition(plan, predictor, name, out, say)
    return conds


def _read_masks(plan: Plan) -> Path:
    """The folder of ``--masks``' PNGs: its ``masks/`` (a ``slimseg dynamic`` output) or
    itself."""
    inner = plan.masks / "masks"
    return inner if inner.is_dir() else plan.masks


def make_predictor(
    model: str | None,
    gt_instances: bool,
    sequence: Path,
    threads: int | None = None,
    dropout: Dropout | None = None,
) -> object:
    """The model's ``Predictor``, or the ``sequence``'s ground-truth instances (with the
    simulated ``dropout``, if any)."""
    if gt_instances:
        from slimseg.dynamic.annotations import AnnotationInstances

        return AnnotationInstances(sequence, dropout)
    from slimseg.deploy.predictor import Predictor

    return Predictor.from_path(model, threads=threads)


def _mode_condition(
    plan: Plan, predictor: object, mode: str, out: Path, say: Callable[[str], None]
) -> Condition:
    from slimseg.sequence.sequence_run import run_sequence

    folder = out / "masks" / mode.replace("+", "_")
    from slimseg.deploy.calibrated import expectation

    meta = None if plan.gt_instances else predictor.metadata
    config = ChainConfig(mode=mode, masking=plan.masking, track=plan.track,
                         keypoints=plan.keypoints,
                         expect=meta and expectation(meta, plan.masking))  # fmt: skip
    rep = run_sequence(predictor, plan.sequence, folder, config, progress=plan.progress)
    ms = rep.ms_per_frame["model"] + rep.ms_per_frame["masking_logic"]
    say(f"{mode}: masks for {rep.frames} frames in {folder / 'masks'} ({ms:.1f} ms/frame)")
    source = "--gt-instances" if plan.gt_instances else "--model"
    settings = preset_name(plan.masking) or "custom"
    note = f"slimseg dynamic --mode {mode} {source}, {settings} settings"
    tags = []
    if plan.gt_instances:
        tags.append("gt instances")
    if plan.dropout is not None:
        tags.append(f"dropout {plan.dropout.rate:g}:{plan.dropout.burst}")
        note += f", --gt-dropout {plan.dropout.rate:g}:{plan.dropout.burst}"
    if plan.track.on:
        rate = plan.track.rate
        tags.append("tracked" + ("" if rate.every_frame else f", model {rate.name}"))
        note += f", --track ({plan.track.describe()})"
    name = f"{mode} ({', '.join(tags)})" if tags else mode
    return Condition(name, "masked", masks=folder / "masks", masking_ms=ms, note=note)


def restored_condition(
    plan: Plan, cond: Condition, out: Path, say: Callable[[str], None]
) -> Condition:
    """Restore every frame of the sequence from ``cond``'s masks (PatchMatch)."""
    from slimseg.sequence.restore_run import restore_sequence

    folder = out / "restore" / cond.name.replace("+", "_").replace(" ", "_")

    def masks(i: int, stamp: float) -> np.ndarray:
        m = decode_file(cond.masks / mask_name(stamp), cv2.IMREAD_GRAYSCALE)
        if m is None:
            raise SlimsegError(f"missing or unreadable mask {cond.masks / mask_name(stamp)}")
        return m

    t0 = time.perf_counter()
    rep = restore_sequence(
        plan.sequence, masks, folder, cond.dilation_px, keypoints=plan.keypoints,
        progress=plan.progress,
    )  # fmt: skip
    ms = 1000 * (time.perf_counter() - t0) / max(rep.frames, 1) + (cond.masking_ms or 0.0)
    say(f"{cond.name} restored: {rep.restored}/{rep.frames} frames in {folder / 'restored'}")
    return Condition(f"{cond.name} restored", "replaced",
                     frames=restored_paths(plan.sequence, folder / "restored"), masking_ms=ms,
                     note=f"PatchMatch restoration of the {cond.name} masks")  # fmt: skip


def refuse_masks_inside(out: Path, masks: Path | None) -> None:
    """``SlimsegError`` when ``--masks`` lives inside a folder of :data:`OWNED` under ``out``
    (a new session replaces those)."""
    if masks is None:
        return
    read = [masks.resolve(), (masks / "masks").resolve()]  # --masks DIR or its masks/
    for p in (out / name for name in OWNED):
        if any(m == p.resolve() or p.resolve() in m.parents for m in read):
            raise SlimsegError(
                f"--masks {masks} is inside {p}, which slam-eval --out {out} replaces: "
                "copy the masks elsewhere or choose another --out"
            )


def clean(out: Path, masks: Path | None) -> None:
    """Delete the previous session's folders under ``out`` (stale runs of another vocabulary
    or intrinsics never mix into a new table); refuse when ``--masks`` lives inside them."""
    refuse_masks_inside(out, masks)
    for p in (out / name for name in OWNED):
        if p.is_dir():
            shutil.rmtree(p)


class EngineOptions(Protocol):
    """What :func:`engine_settings` reads of a plan (:class:`Plan` and the sweep's plan)."""

    engine: str
    features: int
    runs: int
    vocab: Path | None
    realtime: bool
    speed: float
    progress: bool


def engine_settings(plan: EngineOptions, seq: FrameSource, folder: Path) -> EngineRunConfig:
    """The tracking settings of ``plan`` for ``seq``; for ORB-SLAM3 its settings file is
    written into ``folder``."""
    settings = None
    if plan.engine == "orbslam3":
        h, w = seq.load(0)[0].shape[:2]
        orb = OrbSlam3Config(features=plan.features, fps=seq.fps)
        settings = write_settings(folder / "orbslam3_settings.yaml", seq.camera, w, h, orb)
    return EngineRunConfig(
        engine=plan.engine, runs=plan.runs, vocab=plan.vocab, settings=settings,
        realtime=plan.realtime, speed=plan.speed, fps=seq.fps,
        progress=plan.progress,
    )  # fmt: skip


def ground_truth(seq: FrameSource) -> list:
    """The sequence's ``groundtruth.txt`` poses (at least 3, else a one-line error)."""
    gt = read_trajectory(seq.root / "groundtruth.txt")
    if len(gt) < 3:
        raise SlimsegError(f"{seq.root / 'groundtruth.txt'} has {len(gt)} poses: need 3 or more")
    return gt


def run_plan(plan: Plan, out: Path, say: Callable[[str], None]) -> tuple[list[dict], RunInfo]:
    """Everything after option parsing; returns the summary rows and the table's header.
    Writes into ``out`` as it goes: give it an empty folder (``slam-eval`` passes the staging
    folder of :func:`~slimseg.utils.atomic.staged_dir`, which replaces :data:`OWNED` whole)."""
    seq = plan.sequence
    vocab_label = check_engine(plan.engine, plan.vocab)
    say(seq.describe_camera())  # the same line as slimseg dynamic's
    gt = ground_truth(seq) if plan.groundtruth is None else plan.groundtruth()
    masked = mask_conditions(plan, out, say)
    conds: list[Condition] = []
    if "raw" in plan.names:
        conds.append(Condition("raw", "raw", note="the sequence's frames"))
    conds += list(masked.values())
    conds += [restored_condition(plan, masked[n], out, say) for n in plan.restore if n in masked]
    if "oracle" in plan.names:
        if (seq.root / "background" / "rgb").is_dir():
            conds.append(Condition("oracle", "replaced", frames=oracle_paths(seq),
                                   note="true static background (synthetic)"))  # fmt: skip
        else:
            say("oracle: skipped, the sequence has no background/ (synthetic sequences only)")
    if not conds:
        raise SlimsegError("nothing to evaluate: every requested condition was skipped")
    cfg = engine_settings(plan, seq, out)
    results: list[ConditionResult] = []
    for cond in conds:
        res = evaluate_condition(seq, cond, gt, cfg, out / "trajectories")
        s = res.summary()
        ate = "-" if s["ate_rmse"] is None else f"{s['ate_rmse']:.4f} m"
        say(f"{cond.name}: ATE {ate} ({s['scored_runs']}/{s['runs']} runs scored), {s['status']}")
        results.append(res)
    info = RunInfo(
        sequence=seq.root, frames=len(seq), engine=plan.engine, vocabulary=vocab_label,
        intrinsics=seq.camera_source, synthetic=(seq.root / "background").is_dir(),
        runs=plan.runs, groundtruth=gt,
    )  # fmt: skip
    rows = write_report(out, info, results, still_floor(gt_at_frames(gt, seq)))
    if plan.rerun is not None:
        from slimseg.slam.report import table_lines
        from slimseg.slam.rerun_trajectories import write_trajectories

        rrd, shown = write_trajectories(plan.rerun, gt, results, table_lines(rows, True))
        say(f"Rerun recording of {shown} condition trajectories and the ground truth: {rrd}")
    return rows, info
