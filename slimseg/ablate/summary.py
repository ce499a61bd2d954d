"""One summary per arm over its seeds: mean ± spread of every column that varies from run to
run, the cost columns once.

Spread: half the max–min range over the seeds, ``(max − min) / 2`` (0 for a single run), so
``mean ± spread`` spans exactly the values seen; with two seeds it is ``|a − b| / 2``. A NaN
in any run (mask mAP of a detection-only model) makes both NaN.

Varying columns: the row metrics' columns (:mod:`slimseg.ablate.metrics`), the best epoch,
training throughput and every latency column. Cost columns (params, gradients, GFLOPs,
epochs, the spec hash) depend on the arm only and are taken from its first run.
"""

from __future__ import annotations

import math
from typing import Any

from slimseg.ablate.config import AblationConfig
from slimseg.ablate.latency import latency_columns
from slimseg.ablate.metrics import metric_columns

SPREAD_RULE = "mean ± half the max–min range over the seeds"
SPREAD = "_spread"  # suffix of a column's spread in a summary
MEAN = "_mean"  # suffix of a column's mean in summary.csv
RUN_COLUMNS = ("best_epoch", "train_img_s", "latency_ms")
COST_COLUMNS = (
    "epochs",
    "gflops",
    "gflops_paper",
    "gflops_imgsz",
    "gradients",
    "params",
    "params_paper",
    "fused_params",
    "latency_imgsz",
    "val_images",
    "num_classes",
    "spec_hash",
)


def varying_columns(cfg: AblationConfig) -> list[str]:
    """Row columns that change with the seed (or the timing noise), summarised as mean ± spread."""
    latency = latency_columns(cfg.bench_sizes, cfg.bench.masks)
    return [*metric_columns(cfg.metrics), *RUN_COLUMNS, *latency]


def mean_spread(values: list[float]) -> tuple[float, float]:
    """``(mean, (max − min) / 2)`` of ``values``; both NaN if any value is NaN."""
    if not values or any(math.isnan(v) for v in values):
        return math.nan, math.nan
    return math.fsum(values) / len(values), (max(values) - min(values)) / 2


def summarize(rows: list[dict], cfg: AblationConfig) -> list[dict[str, Any]]:
    """Per arm with rows, in the config's order: ``variant``, ``model``, ``runs``, ``seeds``
    (space-separated), each varying column's mean under its own name and its spread under
    ``NAME_spread``, and the cost columns."""
    out = []
    for arm in cfg.variants:
        group = [r for r in rows if r["variant"] == arm.name]
        if not group:
            continue
        s: dict[str, Any] = {
            "variant": arm.name,
            "model": arm.model,
            "runs": len(group),
            "seeds": " ".join(str(r["seed"]) for r in group),
        }
        s |= {k: group[0][k] for k in COST_COLUMNS}
        for key in varying_columns(cfg):
            s[key], s[key + SPREAD] = mean_spread([float(r[key]) for r in group])
        out.append(s)
    return out


def summary_columns(cfg: AblationConfig) -> list[str]:
    """Header of ``summary.csv``: ``NAME_mean`` and ``NAME_spread`` per varying column."""
    pairs = [c for k in varying_columns(cfg) for c in (k + MEAN, k + SPREAD)]
    return ["variant", "model", "runs", "seeds", *pairs, *COST_COLUMNS]


def summary_csv_rows(summaries: list[dict], cfg: AblationConfig) -> list[dict[str, Any]]:
    """Summaries keyed by :func:`summary_columns` (a mean under ``NAME_mean``)."""
    varying = set(varying_columns(cfg))
    return [{(k + MEAN if k in varying else k): v for k, v in s.items()} for s in summaries]
