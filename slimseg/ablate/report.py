"""Sweep results: ``results.csv`` (one row per run), ``summary.csv`` (one per arm: mean and
spread over its seeds, :mod:`slimseg.ablate.summary`), ``results.md`` (the tables, per-seed
rows, and the paper's Table II beside the plain zoo arms) and ``results.png`` (mAP against
GFLOPs and against latency, one labelled point per arm with its spread as error bars)."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

from matplotlib.figure import Figure

from slimseg.ablate.config import AblationConfig
from slimseg.ablate.latency import latency_columns
from slimseg.ablate.mdtable import pct, pm, table
from slimseg.ablate.metrics import BASE_METRIC, metric_columns
from slimseg.ablate.paper_table import paper_key, paper_section
from slimseg.ablate.summary import (
    SPREAD,
    SPREAD_RULE,
    summarize,
    summary_columns,
    summary_csv_rows,
)
from slimseg.eval.paper import TABLE2
from slimseg.utils.atomic import atomic_path, write_text

# results.csv: these first (their order predates arms and seeds), then the model, the
# latency columns of the bench sizes and the columns of any extra row metric.
CSV_COLUMNS = (
    "variant",
    "box_map50_95",
    "seg_map50_95",
    "gflops",
    "gradients",
    "params",
    "epochs",
    "box_map50",
    "seg_map50",
    "best_epoch",
    "fused_params",
    "params_paper",
    "gflops_paper",
    "gflops_imgsz",
    "latency_ms",
    "latency_imgsz",
    "train_img_s",
    "val_images",
    "spec_hash",
    "git_sha",
    "seed",
)


# Headers of the coco metric's columns in the per-seed table (other metrics: column names).
COCO_LABELS = {
    "box_map50_95": "mAP box",
    "seg_map50_95": "mAP seg",
    "box_map50": "mAP50 box",
    "seg_map50": "mAP50 seg",
}


class ReportPaths(NamedTuple):
    csv: Path
    md: Path
    png: Path
    summary: Path


def csv_columns(cfg: AblationConfig) -> list[str]:
    """Header of ``results.csv``."""
    extra = [*latency_columns(cfg.bench_sizes, cfg.bench.masks), *metric_columns(cfg.metrics)]
    return [*CSV_COLUMNS, "model", *(c for c in extra if c not in CSV_COLUMNS)]


def write_reports(rows: list[dict], out: Path, cfg: AblationConfig) -> ReportPaths:
    """Rewrite the four result files from ``rows`` (atomic: temp file, then rename)."""
    summaries = summarize(rows, cfg)
    csv_path = write_text(out / "results.csv", _csv(rows, csv_columns(cfg)))
    summary = _csv(summary_csv_rows(summaries, cfg), summary_columns(cfg))
    summary_path = write_text(out / "summary.csv", summary)
    md_path = write_text(out / "results.md", markdown(rows, cfg))
    png_path = plot_sweep(summaries, out / "results.png", cfg.name)
    return ReportPaths(csv_path, md_path, png_path, summary_path)


def _csv(rows: list[dict], columns: list[str]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(
        {k: round(v, 6) if isinstance(v, float) else v for k, v in r.items()} for r in rows
    )
    return buf.getvalue()


def markdown(rows: list[dict], cfg: AblationConfig) -> str:
    """The sweep's tables (arm summaries), the per-seed rows, the paper beside ours."""
    t = cfg.train
    data = "embedded synthetic set" if cfg.data_path is None else str(cfg.data_path)
    first = rows[0] if rows else {"num_classes": "?", "git_sha": "?", "val_images": "?"}
    seeds = cfg.run_seeds
    multi = len(seeds) > 1
    seed_text = f"seeds {', '.join(map(str, seeds))}" if multi else f"seed {seeds[0]}"
    spread = f" Cells of seed-dependent columns: {SPREAD_RULE}." if multi else ""
    summaries = summarize(rows, cfg)
    size = cfg.bench_sizes[0]

    def acc(s: dict, key: str) -> str:
        return pm(pct(s[key]), pct(s[key + SPREAD]) if multi else None)

    def num(s: dict, key: str, digits: int) -> str:
        return pm(f"{s[key]:.{digits}f}", f"{s[key + SPREAD]:.{digits}f}" if multi else None)

    lines = [
        f"# Ablation sweep `{cfg.name}`",
        "",
        f"Data: {data} ({first['val_images']} val images). Recipe: "
        f"{t.epochs} epochs, batch {t.batch}, {t.imgsz} px, {t.optimizer} lr0 {t.lr0}, "
        f"{seed_text}. mAP: COCO (pycocotools) of the best EMA weights on the val split, "
        f"in %. GFLOPs, gradients and params at nc {first['num_classes']}, "
        f"{cfg.gflops_imgsz} px. Config hash {cfg.hash}, git {first['git_sha']}.{spread}",
        "",
        "## Table II columns",
        "",
        table(
            ["Model", "mAP box", "mAP seg", "GFLOPs", "Gradients (M)", "Params (M)", "Epochs"],
            [
                [
                    s["variant"],
                    acc(s, "box_map50_95"),
                    acc(s, "seg_map50_95"),
                    f"{s['gflops']:.2f}",
                    f"{s['gradients'] / 1e6:.2f}",
                    f"{s['params'] / 1e6:.2f}",
                    str(s["epochs"]),
                ]
                for s in summaries
            ],
        ),
        "",
        "## More measurements",
        "",
        table(
            [
                "Model",
                "mAP50 box",
                "mAP50 seg",
                "best epoch",
                "fused params (M)",
                "GFLOPs paper conv.",
                f"ORT FP32 ms @{size}",
                "train img/s",
                "spec hash",
            ],
            [
                [
                    s["variant"],
                    acc(s, "box_map50"),
                    acc(s, "seg_map50"),
                    num(s, "best_epoch", 1) if multi else str(round(s["best_epoch"])),
                    f"{s['fused_params'] / 1e6:.3f}",
                    f"{s['gflops_paper']:.2f}",
                    num(s, "latency_ms", 1),
                    num(s, "train_img_s", 1),
                    s["spec_hash"],
                ]
                for s in summaries
            ],
        ),
    ]
    if cfg.bench.masks or len(cfg.bench_sizes) > 1:
        lines += ["", *_latency_section(summaries, cfg, num)]
    extra = [c for c in metric_columns(cfg.metrics) if c not in metric_columns([BASE_METRIC])]
    if extra:
        cells = [[s["variant"], *(acc(s, c) for c in extra)] for s in summaries]
        lines += ["", "## Extra row metrics (in %)", "", table(["Model", *extra], cells)]
    if multi:
        lines += ["", *_per_seed_section(rows, cfg)]
    plain = [s for s in summaries if cfg.arm(s["variant"]).plain]
    paired = [(s, TABLE2[k]) for s in plain if (k := paper_key(s["variant"])) is not None]
    if paired:
        lines += ["", *paper_section(plain, paired)]
    return "\n".join(lines) + "\n"


def _latency_section(
    summaries: list[dict], cfg: AblationConfig, num: Callable[[dict, str, int], str]
) -> list[str]:
    b = cfg.bench
    headers, keys = ["Model"], []
    for size in cfg.bench_sizes:
        headers.append(f"net ms @{size}")
        keys.append((f"ms_net@{size}", 2))
        if b.masks:
            headers += [f"post ms @{size}", f"dets @{size}"]
            keys += [(f"ms_post@{size}", 2), (f"dets@{size}", 1)]
    post = (
        f"; post = NMS (conf {b.conf}) + mask assembly (coefficients x prototypes, crop, "
        "upsample to the frame) on the val split's first image, as `slimseg predict` does it; "
        "dets = detections kept on it"
        if b.masks
        else ""
    )
    return [
        "## Latency by input size",
        "",
        f"onnxruntime FP32, static input per size, batch 1, {b.threads} threads, median of "
        f"{b.runs} runs after {b.warmup}: net = the network{post}.",
        "",
        table(headers, [[s["variant"], *(num(s, k, d) for k, d in keys)] for s in summaries]),
    ]


def _per_seed_section(rows: list[dict], cfg: AblationConfig) -> list[str]:
    accuracy = metric_columns(cfg.metrics)
    return [
        "## Per-seed rows (mAP and metrics in %)",
        "",
        table(
            ["Model", "seed", *(COCO_LABELS.get(c, c) for c in accuracy), "best epoch"],
            [
                [r["variant"], str(r["seed"]), *(pct(r[c]) for c in accuracy), str(r["best_epoch"])]
                for r in rows
            ],
        ),
    ]


def plot_sweep(summaries: list[dict], out: Path, title: str) -> Path:
    """mAP50-95 (seg filled, box hollow; error bars: the spread over seeds) against GFLOPs
    and against ORT latency → PNG. ``summaries``: :func:`~slimseg.ablate.summary.summarize`."""
    fig = Figure(figsize=(11, 4.2))
    axes = fig.subplots(1, 2)
    xs = (("gflops", "GFLOPs @{}"), ("latency_ms", "onnxruntime FP32 latency (ms) @{}"))
    for ax, (key, label) in zip(axes, xs, strict=True):
        size = summaries[0]["gflops_imgsz"] if key == "gflops" else summaries[0]["latency_imgsz"]
        for i, s in enumerate(summaries):
            color = f"C{i}"
            x = s[key]
            has_seg = not math.isnan(s["seg_map50_95"])
            for metric, filled in (("seg_map50_95", True), ("box_map50_95", False)):
                if metric == "seg_map50_95" and not has_seg:
                    continue
                ax.errorbar(
                    x,
                    100 * s[metric],
                    yerr=100 * s[metric + SPREAD],
                    xerr=s.get(key + SPREAD),  # latency: spread over seeds; GFLOPs: none
                    fmt="o",
                    ms=7,
                    color=color,
                    mfc=color if filled else "none",
                    capsize=3,
                    zorder=3 if filled else 2,
                )
            y = s["seg_map50_95"] if has_seg else s["box_map50_95"]
            ax.annotate(
                s["variant"], (x, 100 * y), textcoords="offset points", xytext=(5, 5), fontsize=8
            )
        ax.set(xlabel=label.format(f"{size} px"), ylabel="mAP50-95 (%)", ylim=(0, None))
        ax.margins(x=0.3)  # room for the labels of the outermost points
        ax.grid(alpha=0.3)
    axes[0].set_title(
        f"{title}: filled = mask mAP, hollow = box mAP, bars = spread over seeds", fontsize=10
    )
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=110)
    return out
