"""Run an engine on every condition ``runs`` times and score each run against ground truth.

ORB-SLAM3 is multithreaded and not deterministic (the same frames give ATEs tens of percent
apart), so each condition is tracked ``runs`` times and summarised by the median and the
spread (min–max); the dense engine is deterministic and runs once. A run that never
initialises, or keeps fewer than 3 poses, is recorded with its reason instead of a score.

Each ORB-SLAM3 run is made in its own child process (:mod:`slimseg.slam.engine_process`): a
run whose engine crashes, hangs past its timeout or raises is recorded as *failed* with the
cause (``engine crashed (SIGSEGV)``), and the condition's other runs go on.
"""

from __future__ import annotations

import logging
import statistics
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from slimseg.data.frame_source import FrameSource
from slimseg.data.tum import write_trajectory
from slimseg.dynamic.modes import FPS
from slimseg.errors import SlimsegError
from slimseg.slam.conditions import Condition, condition_frames
from slimseg.slam.engine_process import (
    RunFailure,
    SharedFrames,
    default_timeout,
    run_orbslam3_isolated,
)
from slimseg.slam.engines import EngineRun, run_dense
from slimseg.slam.metrics import TrajectoryScore, score

log = logging.getLogger(__name__)

LOST_MARK_FRACTION = 0.1  # a row is marked when the median run lost more than this share


@dataclass(frozen=True)
class EngineRunConfig:
    """``engine``: orbslam3 | dense; ``runs`` per condition (ORB-SLAM3); ``vocab`` /
    ``settings``: ORB-SLAM3 files; ``realtime``: replay at the frame rate times ``speed``;
    ``limit``: first frames only; ``fps``: the sequence's rate; ``timeout_s``: a run's
    limit before its engine process is killed (None: :func:`default_timeout`)."""

    engine: str = "orbslam3"
    runs: int = 3
    vocab: Path | None = None
    settings: Path | None = None
    realtime: bool = True
    speed: float = 1.0
    limit: int | None = None
    fps: float = FPS
    progress: bool = True
    timeout_s: float | None = None


@dataclass
class RunResult:
    """One engine run: its trajectory file, tracking counts and score (or ``error``)."""

    index: int
    frames: int
    lost: int
    reinitialised: int
    tracking_ms: float
    trajectory: Path | None
    score: TrajectoryScore | None = None
    error: str | None = None
    late: int = 0
    """frames fed behind the realtime schedule (``EngineRun.late``)"""
    failed: bool = False
    """the engine returned nothing (crash, timeout, error): ``error`` says why"""


@dataclass
class ConditionResult:
    condition: Condition
    runs: list[RunResult] = field(default_factory=list)

    @property
    def scored(self) -> list[RunResult]:
        return [r for r in self.runs if r.score is not None]

    def median_run(self) -> RunResult | None:
        """The scored run with the median ATE (the lower middle one for an even count)."""
        s = sorted(self.scored, key=lambda r: r.score.ate_rmse)
        return s[(len(s) - 1) // 2] if s else None

    def summary(self) -> dict[str, object]:
        """Median over scored runs of every error, the ATE spread, and tracking counts."""
        scored = self.scored
        ran = [r for r in self.runs if not r.failed]  # failed runs have no counts
        out: dict[str, object] = {
            "condition": self.condition.name,
            "runs": len(self.runs),
            "scored_runs": len(scored),
            "frames": self.runs[0].frames if self.runs else 0,
            "lost_median": _median([r.lost for r in ran]),
            "lost_max": max((r.lost for r in ran), default=0),
            "reinitialised": sum(r.reinitialised for r in ran),
            "tracking_ms": _median([r.tracking_ms for r in ran]),
            "late_max": max((r.late for r in ran), default=0),
            "masking_ms": self.condition.masking_ms,
        }
        for key in ("ate_rmse", "ate_std", "rpe_trans_frame", "rpe_rot_frame", "rpe_trans_s",
                    "rpe_rot_s"):  # fmt: skip
            out[key] = _median([getattr(r.score, key) for r in scored])
        ates = [r.score.ate_rmse for r in scored]
        out["ate_min"] = min(ates) if ates else None
        out["ate_max"] = max(ates) if ates else None
        out["status"] = self.status()
        out["note"] = self.condition.note
        return out

    def status(self) -> str:
        """``ok``, ``lost L/N frames`` (median run over the mark), or why nothing scored;
        then ``, F/R runs failed: <causes>`` when engine runs failed."""
        if not self.scored:
            errors = sorted({r.error for r in self.runs if r.error})
            return "not scored: " + ("; ".join(errors) or "no run")
        failed = [r for r in self.runs if r.failed]
        tail = ""
        if failed:
            causes = "; ".join(f"run {r.index} {r.error}" for r in failed)
            tail = f", {len(failed)}/{len(self.runs)} runs failed: {causes}"
        lost = _median([r.lost for r in self.runs if not r.failed])
        n = self.runs[0].frames
        if lost is not None and lost > LOST_MARK_FRACTION * n:
            return f"lost {int(lost)}/{n} frames{tail}"
        return "ok" + tail


def _median(values: list[float]) -> float | None:
    vals = [v for v in values if v is not None and np.isfinite(v)]
    return float(statistics.median(vals)) if vals else None


def evaluate_condition(
    seq: FrameSource, cond: Condition, gt: np.ndarray, cfg: EngineRunConfig, out: Path
) -> ConditionResult:
    """Track ``cond``'s frames ``cfg.runs`` times; write ``out/<cond>/run<k>.txt`` (TUM)."""
    frames = condition_frames(seq, cond, cfg.limit, cfg.progress)
    result = ConditionResult(cond)
    runs = cfg.runs if cfg.engine == "orbslam3" else 1
    folder = out / _safe(cond.name)
    folder.mkdir(parents=True, exist_ok=True)
    n = len(frames)
    ticks = tqdm(range(runs), desc=f"{cond.name} runs", disable=not cfg.progress or runs < 2)
    if cfg.engine != "orbslam3":
        for k in ticks:
            result.runs.append(_scored(run_dense(frames, seq.camera), k, n, gt, cfg.fps, folder))
        return result
    timeout = cfg.timeout_s or default_timeout(n, cfg.fps, cfg.realtime, cfg.speed)
    with SharedFrames(frames, spill=folder) as shared:
        del frames  # the shared copy is what the runs read
        for k in ticks:
            log_path = folder / "orbslam3.log"
            run = run_orbslam3_isolated(shared, cfg.vocab, cfg.settings, cfg.realtime, log_path,
                                        cfg.speed, timeout, k + 1)  # fmt: skip
            result.runs.append(_scored(run, k, n, gt, cfg.fps, folder))
    return result


def _scored(
    run: EngineRun | RunFailure, k: int, n: int, gt: np.ndarray, fps: float, folder: Path
) -> RunResult:
    if isinstance(run, RunFailure):
        log.warning("%s: run %d failed: %s", folder.name, k + 1, run.reason)
        return RunResult(k + 1, n, n, 0, float("nan"), None, error=run.reason, failed=True)
    path = None
    if len(run.trajectory):
        path = write_trajectory(folder / f"run{k + 1}.txt", run.trajectory)
    res = RunResult(k + 1, n, run.lost, run.reinitialised, run.ms_per_frame, path, late=run.late)
    if not len(run.trajectory):
        res.error = f"never initialised ({n - run.lost}/{n} frames tracked)"
        return res
    try:
        res.score = score(gt, run.trajectory, fps)
    except SlimsegError as e:
        res.error = str(e)
    return res


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)
