"""The search over the masking knobs: Optuna's TPE sampler on the spans the knob registry
declares (:attr:`slimseg.dynamic.knobs.Knob.search`), bounded in time, two candidates at a time.

TPE models each knob's good and bad values from the trials so far, so its cost grows with the
number of trials, not with a grid's product of knob values: adding a knob to the registry adds
a dimension, not a factor. The shipped and the papers' presets are the first two trials, so the
report always says what the chosen settings gain over them. TPE's start is not random points of
the whole space but the shipped preset with :data:`PERTURBED_KNOBS` knobs moved at random
(:func:`nearby`): a 300-s calibration scores 11-20 candidates, and random points of 13
dimensions all leave every knob's shipped value, so the one chosen moved knobs that the few
calibration frames never tested (docs/calibrate.md, round 3). Candidates are ranked by what
they earn over the shipped preset and, among those the cells cannot tell apart, by how few
knobs they move (:func:`preferred`).

Candidates are scored by :func:`slimseg.calibrate.objective.evaluate` in worker processes
(started by a fork server, so no worker copies this process's threads) that receive the
detection caches once.
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import random
import time
from collections.abc import Callable
from dataclasses import dataclass

from slimseg.calibrate.objective import Evaluation, evaluate
from slimseg.dynamic.knobs import KNOBS, Knob, Value
from slimseg.dynamic.masking_settings import PRESETS, MaskingSettings
from slimseg.dynamic.match_memo import MatchMemo, remembered_matches
from slimseg.dynamic.modes import Mode
from slimseg.sequence.detection_cache import DetectionCache

log = logging.getLogger(__name__)

#: The knobs a calibration searches: every masking knob with a search span.
SEARCHED: tuple[Knob, ...] = tuple(k for k in KNOBS if k.group == "masking" and k.search)
#: Trials near the shipped preset before TPE models the results (the two presets come first).
STARTUP_TRIALS = 8
#: Knobs each of those moves away from the shipped preset.
PERTURBED_KNOBS = 3


@dataclass(frozen=True)
class Trial:
    """One candidate: its ``number`` (the order it finished in), ``origin`` (``slimseg`` or
    ``papers``: a preset; ``near``: the shipped preset with a few knobs moved; ``search``: the
    sampler's), the settings' scores and the wall seconds since the search began when it
    finished."""

    number: int
    origin: str
    evaluation: Evaluation
    finished_s: float

    @property
    def value(self) -> float:
        return self.evaluation.value()

    def earned(self, shipped: Trial) -> float:
        """What this candidate earns over the ``shipped`` preset's trial
        (:meth:`~slimseg.calibrate.objective.Evaluation.earned`; NaN objective: -inf)."""
        if math.isnan(self.value):
            return -math.inf
        return self.evaluation.earned(shipped.evaluation)


def suggest(trial: object, k: Knob) -> Value:
    """The value an Optuna ``trial`` proposes for knob ``k`` inside its search span."""
    if k.choices:
        return trial.suggest_categorical(k.key, list(k.choices))
    low, high = k.search
    if k.kind is int:
        return trial.suggest_int(k.key, int(low), int(high), log=k.log)
    return trial.suggest_float(k.key, float(low), float(high), log=k.log)


def tidy(value: Value) -> Value:
    """A proposed float kept to 3 significant digits (the settings a report and a metadata
    entry show; finer steps are below what the objective can tell apart)."""
    return float(f"{value:.3g}") if isinstance(value, float) else value


def clipped(values: dict[str, Value]) -> dict[str, Value]:
    """A preset's values of the searched knobs, each clipped into its span (TPE is told the
    preset as a point of its space)."""
    out: dict[str, Value] = {}
    for k in SEARCHED:
        v = values[k.key]
        out[k.key] = v if k.choices else type(v)(min(max(v, k.search[0]), k.search[1]))
    return out


def nearby(
    rng: random.Random, base: dict[str, Value], moved: int = PERTURBED_KNOBS
) -> dict[str, Value]:
    """``base``'s searched values (clipped into their spans) with ``moved`` knobs drawn anew:
    uniformly in the span (log-uniformly for a ``log`` knob; whole numbers for an int knob),
    or another of a knob's ``choices``. Every knob moved acts under the result's ``rule`` (a
    step of Eq. 1 moved under the degrading rule would score exactly as the preset does)."""
    start = clipped(base)
    while True:
        out = dict(start)
        picked = rng.sample(SEARCHED, min(moved, len(SEARCHED)))
        for k in picked:
            out[k.key] = _draw(rng, k, out[k.key])
        if all(k.rule is None or k.rule == out["rule"] for k in picked):
            return out


def _draw(rng: random.Random, k: Knob, current: Value) -> Value:
    if k.choices:
        return rng.choice([c for c in k.choices if c != current] or list(k.choices))
    lo, hi = float(k.search[0]), float(k.search[1])
    v = math.exp(rng.uniform(math.log(lo), math.log(hi))) if k.log else rng.uniform(lo, hi)
    return min(max(round(v), int(lo)), int(hi)) if k.kind is int else tidy(v)


_WORKER: dict[str, object] = {}
"""A worker process's detection caches and mode (set by :func:`_adopt` in each worker, or for
the length of an in-process search)."""


def _adopt(caches: dict[str, DetectionCache], mode: str) -> None:
    _WORKER.update(caches=caches, mode=mode, matches=MatchMemo())


def _score(settings: MaskingSettings) -> Evaluation:
    # every candidate replays the same frames: their feature matches are computed once
    with remembered_matches(_WORKER["matches"]):  # type: ignore[arg-type]
        return evaluate(settings, _WORKER["caches"], _WORKER["mode"])  # type: ignore[arg-type]


def run_search(
    caches: dict[str, DetectionCache],
    base: MaskingSettings,
    budget_s: float,
    max_trials: int,
    *,
    mode: Mode | str = Mode.FUSION,
    workers: int = 2,
    seed: int = 0,
    on_trial: Callable[[Trial, Trial], None] | None = None,
) -> list[Trial]:
    """Search the :data:`SEARCHED` knobs of ``base`` for at most ``max_trials`` candidates or
    until the next would end after ``budget_s`` seconds; ``on_trial(trial, best)`` after each.
    Returns every trial in the order they finished."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    sampler = optuna.samplers.TPESampler(
        seed=seed, n_startup_trials=STARTUP_TRIALS, multivariate=True
    )
    study = optuna.create_study(direction="maximize", sampler=sampler)
    for name in ("slimseg", "papers"):
        study.enqueue_trial(clipped(PRESETS[name].as_dict()), user_attrs={"origin": name})
    rng = random.Random(seed)
    for _ in range(STARTUP_TRIALS):
        near = nearby(rng, PRESETS["slimseg"].as_dict())
        study.enqueue_trial(near, user_attrs={"origin": "near"})
    t0 = time.perf_counter()
    trials: list[Trial] = []
    pending: dict[object, tuple[object, MaskingSettings, str]] = {}

    def finish(ot: object, settings: MaskingSettings, origin: str, ev: Evaluation) -> None:
        study.tell(ot, ev.value())
        t = Trial(len(trials), origin, ev, time.perf_counter() - t0)
        trials.append(t)
        if on_trial is not None:
            on_trial(t, max(trials, key=lambda x: x.value))

    def ask() -> tuple[object, MaskingSettings, str]:
        ot = study.ask()
        values = {k.key: tidy(suggest(ot, k)) for k in SEARCHED}
        origin = ot.user_attrs.get("origin", "search")
        return ot, base.with_values(**values), origin

    def room() -> bool:
        asked = len(trials) + len(pending)
        elapsed = time.perf_counter() - t0
        per = elapsed / len(trials) * max(workers, 1) if trials else 0.0
        return asked < max_trials and (asked < 2 or elapsed + per <= budget_s)

    if workers <= 1:
        _adopt(caches, str(mode))
        try:
            while room():
                ot, settings, origin = ask()
                finish(ot, settings, origin, _score(settings))
        finally:
            _WORKER.clear()
        return trials
    # forkserver: the workers are forked from a fresh single-threaded server, never from this
    # process, whose native threads (onnxruntime's, Ray's, a trainer's) a fork could copy
    # mid-lock (a worker deadlocked that way inside the test suite); the caches are pickled
    # to each worker once (about 140 MB per 60-frame 640x480 sequence, under a second)
    ctx = multiprocessing.get_context("forkserver")
    with ctx.Pool(workers, initializer=_adopt, initargs=(caches, str(mode))) as pool:
        while room() or pending:
            while room() and len(pending) < workers:
                ot, settings, origin = ask()
                pending[pool.apply_async(_score, (settings,))] = (ot, settings, origin)
            done = next((r for r in pending if r.ready()), None)
            if done is None:
                time.sleep(0.05)
                continue
            ot, settings, origin = pending.pop(done)
            finish(ot, settings, origin, done.get())
    return trials


def moved_keys(trial: Trial, shipped: Trial) -> list[str]:
    """The searched knobs ``trial`` moves from ``shipped``'s values, only those that act
    under its rule (a knob of the other rule changes nothing)."""
    mine = clipped(trial.evaluation.settings.as_dict())
    base = clipped(shipped.evaluation.settings.as_dict())
    acts = [k for k in SEARCHED if k.rule is None or k.rule == mine["rule"]]
    return [k.key for k in acts if mine[k.key] != base[k.key]]


def moved(trial: Trial, shipped: Trial) -> int:
    """How many searched knobs ``trial`` moves from ``shipped``'s values
    (:func:`moved_keys`)."""
    return len(moved_keys(trial, shipped))


def preferred(trials: list[Trial], shipped: Trial) -> list[Trial]:
    """``trials`` that earn anything over ``shipped`` (:meth:`Trial.earned` > 0), in order
    of preference; then ``shipped``. The one-standard-error rule of model selection: the
    candidates whose mean gain is within one standard error of the best mean gain
    (:meth:`~slimseg.calibrate.objective.Evaluation.gain`) cannot be told apart on these
    cells, so among them the fewest knobs moved comes first (the most earned on a tie); the
    others follow by what they earn. A calibration's eight cells put a standard error of
    0.2-0.6 on the gains, and a candidate of TPE's that moved all twelve knobs led one of the
    start's that moved three by 0.03 (docs/calibrate.md, round 4)."""
    gains = {t.number: t.evaluation.gain(shipped.evaluation) for t in trials}
    earning = [t for t in trials if t.earned(shipped) > 0 and t.number != shipped.number]
    if not earning:
        return [shipped]
    top = max(earning, key=lambda t: gains[t.number][0])
    bar = gains[top.number][0] - gains[top.number][1]
    level = [t for t in earning if gains[t.number][0] >= bar]
    rest = [t for t in earning if gains[t.number][0] < bar]
    level.sort(key=lambda t: (moved(t, shipped), -t.earned(shipped), t.number))
    rest.sort(key=lambda t: (-t.earned(shipped), t.number))
    return [*level, *rest, shipped]


def best(trials: list[Trial]) -> Trial:
    """The preferred trial (:func:`preferred`); without the shipped preset among ``trials``:
    the highest objective (the earliest on a tie)."""
    shipped = next((t for t in trials if t.origin == "slimseg"), None)
    if shipped is None:
        return max(trials, key=lambda t: (t.value, -t.number) if not math.isnan(t.value) else -1e9)
    return preferred(trials, shipped)[0]
