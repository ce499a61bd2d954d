"""The calibration's report: ``report.json`` (every candidate's settings and scores, the
confirmation's ATEs, the timings), ``report.md`` (the tables a reader wants) and
``report.png`` (what each candidate earned over the shipped preset, over time; precision
against recall per candidate, the shipped and chosen settings marked; the confirmation's
ATEs).

:func:`digest` of ``report.json`` is what the calibrated export's metadata records, so a model
names the report its settings came from.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any

from slimseg.calibrate.objective import (
    EARN_SE,
    RECALL_FLOOR,
    RECALL_TARGET,
    RECALL_WEIGHT,
    Evaluation,
)
from slimseg.calibrate.run import CalibrationResult
from slimseg.calibrate.search import SEARCHED, Trial, moved_keys
from slimseg.utils.atomic import atomic_path, write_text


def _num(v: float) -> float | None:
    return None if math.isnan(v) else round(float(v), 5)


def _scores(ev: Evaluation) -> dict[str, Any]:
    cells = [
        {
            "sequence": c.sequence,
            "condition": c.condition,
            "precision": _num(c.precision),
            "recall": _num(c.recall),
            "walker_recall": _num(c.walker_recall),
            "logic_ms": round(c.logic_ms, 2),
        }
        for c in ev.cells
    ]
    return {"objective": _num(ev.value()), "cells": cells}


def report_dict(result: CalibrationResult, model: Path) -> dict[str, Any]:
    """The report as JSON-ready data."""
    trials = [
        {
            "number": t.number,
            "origin": t.origin,
            "finished_s": round(t.finished_s, 2),
            "settings": {k.key: t.evaluation.settings.as_dict()[k.key] for k in SEARCHED},
            "earned": _num(max(t.earned(result.shipped), -1e9)),
            **_scores(t.evaluation),
        }
        for t in result.trials
    ]
    confirmation = None
    if result.truth_ate is not None:
        confirmation = {
            "ground_truth_masks": result.truth_ate.as_dict(),
            "candidates": {str(n): a.as_dict() for n, a in result.ates.items()},
        }
    return {
        "model": model.name,
        "calibrated_on": result.calibration_set.describe(),
        "objective": {
            "recall_target": RECALL_TARGET,
            "recall_floor": RECALL_FLOOR,
            "recall_weight": RECALL_WEIGHT,
            "shortfall": "sum over cells of max(0, floor - min(recall, walker_recall))",
            "earned": f"mean paired per-cell gain over the shipped preset - {EARN_SE:g} SE",
            "conditions": ["per_frame", "track"],
        },
        "searched": [k.key for k in SEARCHED],
        "shipped": result.shipped.number,
        "chosen": result.chosen.number,
        "settings": result.settings.as_dict(),
        "trials": trials,
        "confirmation": confirmation,
        "seconds": {k: round(v, 1) for k, v in result.seconds.items()},
        "model_ms": round(result.model_ms, 1),
    }


def digest(path: Path) -> str:
    """``sha256:<hex>`` of a report file."""
    return "sha256:" + hashlib.sha256(path.read_bytes()).hexdigest()


def _pct(v: float) -> str:
    return "–" if math.isnan(v) else f"{100 * v:.1f} %"


def _row(label: str, t: Trial, result: CalibrationResult) -> str:
    ev = t.evaluation
    pf, tr = ev.pooled("per_frame"), ev.pooled("track")
    ate = result.ates.get(t.number)
    ates = "–" if ate is None else f"{ate.median:.4f} m"
    walkers = " / ".join(_pct(ev.walkers(c)) for c in ("per_frame", "track"))
    return (
        f"| {label} | {ev.value():.3f} | {t.earned(result.shipped):.3f} | "
        f"{_pct(pf[0])} / {_pct(pf[1])} | {_pct(tr[0])} / {_pct(tr[1])} | {walkers} | {ates} |"
    )


def report_markdown(result: CalibrationResult, model: Path) -> str:
    """The report's tables: before / after, the chosen settings, where each candidate went."""
    lines = [f"# Calibration of {model.name}", ""]
    on = result.calibration_set.describe()
    lines += [f"Calibrated on: `{json.dumps(on)}`", ""]
    lines += [
        "| settings | objective | earned over shipped | per frame precision / recall "
        "| track precision / recall | walker-frames kept, per frame / track "
        "| ORB-SLAM3 ATE (median) |",
        "|---|---|---|---|---|---|---|",
    ]
    lines.append(_row("shipped (slimseg)", result.shipped, result))
    lines.append(_row(f"chosen (candidate {result.chosen.number})", result.chosen, result))
    if result.truth_ate is not None:
        lines.append(
            f"| ground-truth masks | – | – | – | – | – | {result.truth_ate.median:.4f} m |"
        )
    lines += ["", "Chosen settings:", ""]
    lines += [f"- `{k}` = {v}" for k, v in result.settings.as_dict().items()]
    moved = moved_keys(result.chosen, result.shipped)
    lines += ["", f"Knobs moved from the shipped preset: {', '.join(moved) or 'none'}."]
    secs = ", ".join(f"{k} {v:.0f} s" for k, v in result.seconds.items())
    lines += ["", f"{len(result.trials)} candidates; time: {secs}.", ""]
    return "\n".join(lines)


def write_plot(result: CalibrationResult, path: Path) -> Path:
    """``report.png``: what each candidate earned over time, precision vs recall, the
    confirmation's ATEs."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(15, 4.8), dpi=100)
    FigureCanvasAgg(fig)
    over, pr, bars = fig.subplots(1, 3)
    shipped = result.shipped
    for origin, color, label in (
        ("near", "tab:purple", "the shipped preset, 3 knobs moved"),
        ("search", "tab:blue", "TPE's candidate"),
        ("papers", "tab:red", "the papers' preset"),
    ):
        mine = [t for t in result.trials if t.origin == origin]
        over.scatter([t.finished_s for t in mine], [max(t.earned(shipped), -1.0) for t in mine],
                     s=14, color=color, label=label)  # fmt: skip
    chosen = result.chosen
    over.scatter([chosen.finished_s], [max(chosen.earned(shipped), -1.0)], s=90,
                 facecolor="none", edgecolor="tab:green", lw=2, label="chosen")  # fmt: skip
    over.axhline(0.0, color="tab:orange", ls="--", lw=1, label="shipped preset (earns 0)")
    over.set(
        xlabel="search time (s)",
        ylabel="earned over the shipped preset",
        title="what each candidate earns (mean gain − 1 SE)",
    )
    over.legend(fontsize=7)
    for cond, marker in (("per_frame", "o"), ("track", "^")):
        pts = [t.evaluation.pooled(cond) for t in result.trials]
        pr.scatter(
            [r for _, r in pts],
            [p for p, _ in pts],
            s=12,
            marker=marker,
            alpha=0.45,
            label=f"candidates, {cond.replace('_', ' ')}",
        )
        for t, color, name in (
            (result.shipped, "tab:orange", "shipped"),
            (result.chosen, "tab:green", "chosen"),
        ):
            p, r = t.evaluation.pooled(cond)
            pr.scatter(
                [r],
                [p],
                s=70,
                marker=marker,
                color=color,
                edgecolor="k",
                label=f"{name}, {cond.replace('_', ' ')}",
            )
    pr.axvline(RECALL_FLOOR, color="k", ls=":", lw=1, label="floor the search holds")
    pr.axvline(RECALL_TARGET, color="grey", ls="--", lw=1, label="target on other sequences")
    pr.set(
        xlabel="dynamic-keypoint recall", ylabel="precision", title="keypoints (mean of sequences)"
    )
    pr.legend(fontsize=7)
    if result.truth_ate is not None:
        labels = ["ground truth"] + [f"#{n}" for n in result.confirmed]
        runs = [result.truth_ate.ates] + [result.ates[n].ates for n in result.confirmed]
        med = [min(result.truth_ate.median, 1.0)] + [
            min(result.ates[n].median, 1.0) for n in result.confirmed
        ]
        colors = ["0.5"] + [
            "tab:green"
            if n == result.chosen.number
            else "tab:orange"
            if n == result.shipped.number
            else "tab:blue"
            for n in result.confirmed
        ]
        bars.bar(range(len(med)), med, color=colors)
        for i, r in enumerate(runs):
            bars.scatter([i] * len(r), r, color="k", s=10, zorder=3)
        bars.set_xticks(range(len(med)), labels)
        bars.set(ylabel="ATE RMSE (m)", title="ORB-SLAM3 confirmation (bars: median, dots: runs)")
    else:
        bars.text(
            0.5,
            0.5,
            "no ORB-SLAM3 confirmation\n(--confirm-runs 0)",
            ha="center",
            va="center",
            transform=bars.transAxes,
        )
        bars.set_axis_off()
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return path


def write_report(result: CalibrationResult, model: Path, folder: Path) -> str:
    """Write ``report.json``, ``report.md`` and ``report.png`` into ``folder``; returns the
    JSON's :func:`digest`."""
    write_text(folder / "report.json", json.dumps(report_dict(result, model), indent=1))
    write_text(folder / "report.md", report_markdown(result, model))
    write_plot(result, folder / "report.png")
    return digest(folder / "report.json")
