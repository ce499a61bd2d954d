"""Plots people would rather look at than read: training curves and prediction grids."""

from __future__ import annotations

import csv
import os
from pathlib import Path

from matplotlib.figure import Figure

SEMANTIC_KEYS = ("val/miou", "val/mpa")  # semantic models (MSNET)


def plot_results(csv_path: str | Path, out: str | Path | None = None) -> Path:
    """Loss terms and validation mAP (mIoU / MPA for semantic models) per epoch from a run's
    ``results.csv`` → PNG."""
    csv_path = Path(csv_path)
    with csv_path.open() as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError(f"{csv_path}: no rows to plot")
    epochs = [int(r["epoch"]) + 1 for r in rows]
    losses = [k for k in rows[0] if k.startswith("train/")]
    maps = [k for k in rows[0] if k.startswith("val/") and ("map" in k or k in SEMANTIC_KEYS)]
    fig = Figure(figsize=(10, 3.6))
    axes = fig.subplots(1, 2)
    for key in losses:
        axes[0].plot(epochs, [float(r[key]) for r in rows], marker="o", label=key[6:])
    axes[0].set(title="training loss terms (before gains)", xlabel="epoch")
    for key in maps:
        axes[1].plot(epochs, [float(r[key]) for r in rows], marker="o", label=key[4:])
    title = "validation mIoU / MPA" if "val/miou" in maps else "validation mAP"
    axes[1].set(title=f"{title} (EMA weights)", xlabel="epoch", ylim=(0, None))
    for ax in axes:
        ax.grid(alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=8)
    fig.tight_layout()
    out = Path(out) if out else csv_path.with_suffix(".png")
    tmp = out.with_name(f".{out.name}.tmp.png")
    fig.savefig(tmp, dpi=110)
    os.replace(tmp, out)
    return out
