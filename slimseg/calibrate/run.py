"""One calibration, end to end: sequences → detections once → search → ORB-SLAM3 confirmation
→ the chosen settings written into a copy of the export, with a report beside it.

Time: ``budget_s`` bounds the whole run. Rendering and the detection caches come first; the
confirmation's share is reserved from an estimate of its runs; the search gets the rest and
stops asking for candidates when the next would overrun it.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from slimseg.calibrate.confirm import (
    CONFIRM_CANDIDATES,
    CONFIRM_RUNS,
    Ate,
    EngineSetup,
    choose,
    confirm,
)
from slimseg.calibrate.objective import conf_floor
from slimseg.calibrate.search import SEARCHED, Trial, best, preferred, run_search
from slimseg.calibrate.sequences import (
    CALIBRATION_FRAMES,
    CALIBRATION_PRESETS,
    CALIBRATION_SIZE,
    CalibrationSet,
    PreloadedSequence,
    render_calibration_set,
    user_calibration_set,
)
from slimseg.dynamic.masking_settings import DEFAULT, MaskingSettings
from slimseg.dynamic.modes import Mode
from slimseg.sequence.detection_cache import DetectionCache, build_cache

log = logging.getLogger(__name__)

#: Default time bound of a calibration (s) and its cap on candidates.
DEFAULT_BUDGET_S = 300.0
DEFAULT_MAX_TRIALS = 200
#: Rendered calibration sequences by default: one of each preset (two of each left a 300 s
#: calibration 5 candidates on an idle 2-core machine, docs/calibrate.md; --sequences adds more).
DEFAULT_SEQUENCES = len(CALIBRATION_PRESETS)
#: Seconds an ORB-SLAM3 run costs beyond replaying its frames (start, vocabulary, shutdown),
#: and building the small vocabulary when none is given.
RUN_OVERHEAD_S = 4.0
VOCABULARY_S = 15.0
#: The confirmation runs only when it fits in this share of the time left after the detections.
CONFIRM_SHARE = 0.6


@dataclass(frozen=True)
class CalibrationPlan:
    """What to calibrate and how: the export ``model``, the user's ``sequences`` (empty:
    render ``rendered`` of them, ``frames`` frames of ``size`` W×H each), the ``mode``, the
    time ``budget_s``, the search's ``max_trials``, ``workers`` and ``seed``, and the
    confirmation (``confirm_runs`` ORB-SLAM3 runs per condition, 0: none; ``vocab``:
    ORB-SLAM3's vocabulary, None: built from the calibration frames)."""

    model: Path
    sequences: tuple[Path, ...] = ()
    rendered: int = DEFAULT_SEQUENCES
    frames: int = CALIBRATION_FRAMES
    size: tuple[int, int] = CALIBRATION_SIZE
    mode: str = Mode.FUSION.value
    budget_s: float = DEFAULT_BUDGET_S
    max_trials: int = DEFAULT_MAX_TRIALS
    workers: int = 2
    seed: int = 0
    confirm_runs: int = CONFIRM_RUNS
    vocab: Path | None = None
    threads: int | None = 1
    progress: bool = True


@dataclass
class CalibrationResult:
    """Everything the report shows: the set, the trials, the shipped and chosen trials, the
    confirmation's ATEs (empty: none ran), the timings (s) of each step."""

    calibration_set: CalibrationSet
    trials: list[Trial]
    shipped: Trial
    chosen: Trial
    truth_ate: Ate | None = None
    ates: dict[int, Ate] = field(default_factory=dict)
    confirmed: list[int] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    model_ms: float = 0.0

    @property
    def settings(self) -> MaskingSettings:
        return self.chosen.evaluation.settings


def confirm_estimate_s(plan: CalibrationPlan, frames: int, fps: float) -> float:
    """Seconds the confirmation will take: (candidates + shipped + ground truth) conditions x
    runs x (the replay at the engine's speed + the overhead)."""
    if plan.confirm_runs < 1:
        return 0.0
    per_run = frames / fps / EngineSetup(Path()).speed + RUN_OVERHEAD_S
    return (CONFIRM_CANDIDATES + 2) * plan.confirm_runs * per_run


def calibrate(
    plan: CalibrationPlan, work: Path, say: Callable[[str], None] = log.info
) -> CalibrationResult:
    """Run ``plan``; sequences, vocabulary and confirmation files go under ``work``."""
    t0 = time.perf_counter()
    seconds: dict[str, float] = {}
    if plan.sequences:
        cal_set = user_calibration_set(list(plan.sequences))
    else:
        say(
            f"rendering {plan.rendered} calibration sequences (indices no training world or "
            "evaluation sequence uses)"
        )
        cal_set = render_calibration_set(
            work / "sequences", plan.rendered, plan.frames, plan.size, plan.workers
        )
    seconds["sequences"] = time.perf_counter() - t0
    caches = _caches(plan, cal_set, say)
    seconds["detections"] = time.perf_counter() - t0 - seconds["sequences"]
    first = next(iter(caches.values()))
    reserve = confirm_estimate_s(plan, len(first.frames), first.sequence.fps)
    if plan.confirm_runs and plan.vocab is None:
        reserve += VOCABULARY_S
    left = plan.budget_s - (time.perf_counter() - t0)
    if plan.confirm_runs and reserve > CONFIRM_SHARE * left:
        say(
            f"no ORB-SLAM3 confirmation: it would take about {reserve:.0f} s of the "
            f"{max(left, 0):.0f} s left (raise --budget)"
        )
        plan, reserve = replace(plan, confirm_runs=0), 0.0
    search_s = max(plan.budget_s - (time.perf_counter() - t0) - reserve, 0.0)
    say(
        f"searching {len(SEARCHED)} knobs for {search_s:.0f} s (at most {plan.max_trials} "
        f"candidates, {plan.workers} at a time; {reserve:.0f} s kept for the confirmation)"
    )
    trials = _search(plan, caches, search_s)
    seconds["search"] = time.perf_counter() - t0 - sum(seconds.values())
    shipped = next(t for t in trials if t.origin == "slimseg")
    result = CalibrationResult(cal_set, trials, shipped, best(trials), seconds=seconds)
    result.model_ms = sum(c.model_ms for c in caches.values()) / len(caches)
    if plan.confirm_runs:
        _confirm(plan, caches, result, work, say)
    seconds["confirm"] = time.perf_counter() - t0 - sum(seconds.values())
    seconds["total"] = time.perf_counter() - t0
    return result


def _caches(
    plan: CalibrationPlan, cal_set: CalibrationSet, say: Callable[[str], None]
) -> dict[str, DetectionCache]:
    from slimseg.deploy.predictor import Predictor

    lowest = min(float(k.search[0]) for k in SEARCHED if k.key == "conf")
    predictor = Predictor.from_path(str(plan.model), threads=plan.threads)
    caches = {}
    for folder in cal_set.folders:
        seq = PreloadedSequence(folder)
        caches[folder.name] = build_cache(
            predictor, seq, conf_floor(lowest), progress=plan.progress
        )
        say(
            f"  {folder.name}: {len(seq)} frames, model {caches[folder.name].model_ms:.0f} ms/frame"
        )
    return caches


def _search(
    plan: CalibrationPlan, caches: dict[str, DetectionCache], search_s: float
) -> list[Trial]:
    """The search with a progress bar over its time budget (candidates and the best so far
    beside it)."""
    from tqdm import tqdm

    total = max(round(search_s), 1)
    bar = tqdm(total=total, desc="calibrate", unit="s", disable=not plan.progress)
    count = 0

    def show(trial: Trial, leader: Trial) -> None:
        nonlocal count
        count += 1
        p, r = leader.evaluation.pooled("track")
        bar.n = min(round(trial.finished_s), total)
        bar.set_postfix_str(f"{count} candidates, best {leader.value:.3f} (tracked precision "
                            f"{p:.0%}, recall {r:.0%})")  # fmt: skip

    try:
        return run_search(caches, DEFAULT, search_s, plan.max_trials, mode=plan.mode,
                          workers=plan.workers, seed=plan.seed, on_trial=show)  # fmt: skip
    finally:
        bar.close()


def _confirm(
    plan: CalibrationPlan,
    caches: dict[str, DetectionCache],
    result: CalibrationResult,
    work: Path,
    say: Callable[[str], None],
) -> None:
    """Track the preferred candidates (:func:`~slimseg.calibrate.search.preferred`) and the
    shipped preset; choose (:func:`confirm.choose`). None earning anything: the shipped
    preset, untracked."""
    seen, picked = {tuple(sorted(result.shipped.evaluation.settings.as_dict().items()))}, []
    for t in preferred(result.trials, result.shipped):
        key = tuple(sorted(t.evaluation.settings.as_dict().items()))
        if key not in seen:
            seen.add(key)
            picked.append(t)
        if len(picked) == CONFIRM_CANDIDATES:
            break
    if not picked:
        say("no candidate earns anything over the shipped preset: the shipped preset stays")
        result.chosen = result.shipped
        return
    candidates = [*picked, result.shipped]
    name, cache = next(iter(caches.items()))
    vocab = plan.vocab or _vocabulary(cache, work / "vocab.txt", say)
    setup = EngineSetup(vocab, runs=plan.confirm_runs, progress=plan.progress)
    say(
        f"confirming {len(candidates)} candidates with ORB-SLAM3 on {name} "
        f"({plan.confirm_runs} runs each, beside the ground-truth masks)"
    )
    truth, ates = confirm(
        cache.sequence, cache, candidates, setup, work / "confirm", plan.mode, say
    )
    result.truth_ate, result.ates = truth, ates
    result.confirmed = [t.number for t in candidates]
    result.chosen = choose(candidates, truth, ates, result.shipped)


def _vocabulary(cache: DetectionCache, out: Path, say: Callable[[str], None]) -> Path:
    from slimseg.slam.vocab import small_vocabulary

    frames = [cache.sequence.load(i)[0] for i in range(len(cache.sequence))]
    say(f"building a small ORB vocabulary from the {len(frames)} calibration frames")
    small_vocabulary(frames, out)
    return out
