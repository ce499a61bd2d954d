"""``sweep.csv``, ``sweep.md`` and ``sweep.png`` of a masking-settings sweep.

One row per (sequence, condition): the references (raw frames, ground-truth masks) and every
setting, with the ATE median and min–max over runs, RPE, keypoint precision / recall of the
setting's masks against ``dynamic/``, masking time per frame and tracking losses. The plot has
one row of panels per sequence and one panel per swept key: ATE (median, min–max bars) against
the key's value through the base settings (oneway) or through the best point (grid),
precision / recall on a twin axis, raw and ground-truth ATE as horizontal lines.
"""

from __future__ import annotations

import math
from pathlib import Path

from slimseg.slam.condition_runs import ConditionResult
from slimseg.slam.report import csv_text
from slimseg.slam.sweep import (
    SWEEP_KEYS,
    TRACK_SWEEP_KEYS,
    SweepPoint,
    format_value,
    key_value,
    slice_through,
)
from slimseg.slam.sweep_run import SequenceSweep, SweepPlan
from slimseg.utils.atomic import atomic_path, write_text
from slimseg.utils.table import format_table

SETTING_COLUMNS = SWEEP_KEYS + tuple(f"track_{k}" for k in TRACK_SWEEP_KEYS)
COLUMNS = (
    "sequence", "condition", "kind", *SETTING_COLUMNS, "ate_rmse", "ate_min", "ate_max",
    "ate_std", "rpe_trans_s", "rpe_rot_s", "precision", "recall", "tp", "fp", "fn",
    "model_ms", "logic_ms", "masking_ms", "tracking_ms", "late_max", "lost_median", "lost_max",
    "reinitialised",
    "scored_runs", "runs", "status", "same_masks_as",
)  # fmt: skip


def sweep_rows(sw: SequenceSweep) -> list[dict]:
    """The rows of one sequence (:data:`COLUMNS`): raw, gt, then every point in order."""
    rows = []
    for kind, res in (("raw", sw.raw), ("gt", sw.gt)):
        if res is not None:
            row = _row(sw, res, kind)
            if kind == "gt":
                row["dilation_px"] = sw.gt_dilation_px
            rows.append(row)
    for p in sw.points:
        row = _row(sw, sw.results[p.label], "reference" if p.reference else "point")
        row.update(p.settings.as_dict())
        row.update({f"track_{k}": key_value(p.settings, p.track, k) for k in TRACK_SWEEP_KEYS})
        sm = sw.masks[p.label]
        if sm.score is not None:
            s = sm.score
            row.update(precision=s.precision, recall=s.recall, tp=s.tp, fp=s.fp, fn=s.fn)
        row.update(model_ms=sw.model_ms, logic_ms=sm.logic_ms, masking_ms=sw.model_ms + sm.logic_ms)
        if p.label in sw.same_as:
            row["same_masks_as"] = sw.same_as[p.label]
            row["status"] = f"masks = {sw.same_as[p.label]}'s (its runs)"
        rows.append(row)
    return rows


def _row(sw: SequenceSweep, res: ConditionResult, kind: str) -> dict:
    s = res.summary()
    row = dict.fromkeys(COLUMNS)
    row.update({k: s[k] for k in COLUMNS if k in s})
    row.update(sequence=sw.label, condition=res.condition.name, kind=kind)
    return row


def _m(v: object, digits: int = 4) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"


def _pct(v: object) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{100 * v:.1f}"


def table(rows: list[dict], keys: list[str], markdown: bool = True) -> str:
    """The human table of one sequence's rows, with a column per swept key."""
    headers = ["condition", *keys, "ATE m (median)", "min–max", "RPE m/s", "precision %",
               "recall %", "mask ms/frame", "lost (median/max)", "reinit", "late",
               "status"]  # fmt: skip
    body = []
    for r in rows:
        spread = "-" if r["ate_min"] is None else f"{r['ate_min']:.4f}–{r['ate_max']:.4f}"
        cols = [f"track_{k}" if k in TRACK_SWEEP_KEYS else k for k in keys]
        vals = ["" if r[c] is None else format_value(r[c]) for c in cols]
        lost = "-" if r["lost_median"] is None else f"{int(r['lost_median'])}/{r['lost_max']}"
        body.append([r["condition"], *vals, _m(r["ate_rmse"]), spread, _m(r["rpe_trans_s"]),
                     _pct(r["precision"]), _pct(r["recall"]), _m(r["masking_ms"], 1), lost,
                     "-" if r["reinitialised"] is None else str(r["reinitialised"]),
                     "-" if r["late_max"] is None else str(r["late_max"]),
                     r["status"]])  # fmt: skip
    return format_table(headers, body, markdown=markdown)


def write_sweep(out: Path, plan: SweepPlan, sweeps: list[SequenceSweep], model: str) -> list:
    """Write the three files under ``out`` (each atomically); returns every row."""
    keys = list(plan.spec)
    all_rows: list[dict] = []
    runs = plan.runs if plan.engine == "orbslam3" else 1
    lines = [
        "# slam-eval sweep",
        "",
        f"- masks: `--modes {plan.mode}`, {model}; base settings: {plan.base.describe()}",
        f"- track stage: {plan.track.describe()}"
        + ("" if plan.dropout is None else
           f"; ground-truth dropout {plan.dropout.rate:g} in bursts of {plan.dropout.burst}"),
        f"- sweep: {plan.how} over " + ", ".join(f"{k} = {', '.join(format_value(v) for v in vals)}"
                                                 for k, vals in plan.spec.items()),
        f"- engine: {plan.engine}, {runs} run(s) per setting (ATE median, min–max), "
        + (f"realtime feeding at {plan.speed:g}x the frame rate (late: frames fed behind it)"
           if plan.realtime else "as-fast-as-possible feeding"),
        "- precision / recall: dynamic ORB keypoints of the masks vs the ground-truth dynamic/ "
        "masks; mask ms/frame: model (run once per frame, shared by all settings) + masking "
        "logic",
        "",
    ]  # fmt: skip
    for sw in sweeps:
        rows = sweep_rows(sw)
        all_rows += rows
        seq = sw.sequence
        lines += [
            f"## {sw.label}",
            "",
            f"`{seq.root}`: {len(seq)} frames; vocabulary {sw.vocabulary}; intrinsics "
            f"{seq.camera_source}; model {sw.model_ms:.1f} ms/frame; still-camera floor "
            f"{sw.floor:.4f} m",
            "",
            table(rows, keys),
            "",
        ]
    plot_sweep(out / "sweep.png", plan, sweeps)
    write_text(out / "sweep.csv", csv_text(all_rows, COLUMNS))
    write_text(out / "sweep.md", "\n".join(lines))
    return all_rows


def center_point(plan: SweepPlan, sw: SequenceSweep) -> SweepPoint:
    """The point the plotted curves pass through: the base (oneway) or the lowest median ATE
    of the grid (the base where nothing scored)."""
    points = [p for p in sw.points if not p.reference]
    if plan.how == "oneway":
        return points[0]
    scored = [p for p in points if sw.results[p.label].summary()["ate_rmse"] is not None]
    return min(scored, key=lambda p: sw.results[p.label].summary()["ate_rmse"], default=points[0])


def plot_sweep(path: Path, plan: SweepPlan, sweeps: list[SequenceSweep]) -> None:
    """The sweep figure (see the module docstring), written atomically."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    keys = list(plan.spec)
    fig = Figure(figsize=(4.2 * len(keys), 3.4 * len(sweeps)), dpi=100)
    axes = fig.subplots(len(sweeps), len(keys), squeeze=False)
    for row, sw in enumerate(sweeps):
        center = center_point(plan, sw)
        for col, key in enumerate(keys):
            _panel(axes[row][col], sw, key, slice_through(sw.points, key, center))
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp)


def _panel(ax, sw: SequenceSweep, key: str, points: list[SweepPoint]) -> None:
    xs, med, lo, hi, prec, rec = [], [], [], [], [], []
    for p in points:
        s = sw.results[p.label].summary()
        if s["ate_rmse"] is None:
            continue
        xs.append(key_value(p.settings, p.track, key))
        med.append(s["ate_rmse"])
        lo.append(s["ate_rmse"] - s["ate_min"])
        hi.append(s["ate_max"] - s["ate_rmse"])
        score = sw.masks[p.label].score
        prec.append(100 * score.precision if score else math.nan)
        rec.append(100 * score.recall if score else math.nan)
    ax.errorbar(xs, med, yerr=[lo, hi], fmt="o-", color="C0", capsize=3, label="ATE (median)")
    for res, name, color in ((sw.raw, "raw", "C3"), (sw.gt, "gt masks", "C2")):
        ate = res.summary()["ate_rmse"] if res is not None else None
        if ate is not None:
            ax.axhline(ate, ls="--", color=color, lw=1, label=f"{name} {ate:.3f} m")
    ax.set_yscale("log")
    ax.set_xlabel(key)
    ax.set_ylabel("ATE RMSE (m)")
    ax.set_title(f"{sw.label}: {key}", fontsize=9)
    twin = ax.twinx()
    twin.plot(xs, prec, "s:", color="C1", ms=4, label="precision %")
    twin.plot(xs, rec, "^:", color="C4", ms=4, label="recall %")
    twin.set_ylim(0, 105)
    twin.set_ylabel("keypoints %")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = twin.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=6, loc="best")
