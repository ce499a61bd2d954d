"""Sweep results as ``results.csv``, ``results.md`` (with the paper's Table II beside ours)
and ``results.png`` (mAP against GFLOPs and against latency, one labelled point per variant)."""

from __future__ import annotations

import csv
import io
import math
import re
from pathlib import Path

from matplotlib.figure import Figure

from slimseg.ablate.config import AblationConfig
from slimseg.eval.paper import TABLE2, TABLE2_IMGSZ, TABLE2_NUM_CLASSES, PaperRow
from slimseg.utils.atomic import atomic_path, write_text

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

NOTES = """\
How to read the two tables:
- Scale and recipe differ: the paper trained the s-scale variants for 500 epochs on COCO-20 at
  640 px; a synthetic CPU sweep trains n-scale variants for minutes. Compare the *changes
  against each table's baseline row*, not the absolute mAP.
- GFLOPs: ours are 2 x multiply-adds counted by torch's FlopCounterMode in eval mode. The
  paper's tool (thop through the reference code) also counts 4 operations per BatchNorm
  output and overcounts ConvTranspose; "GFLOPs paper conv." applies that convention, and at
  s scale, nc 20, 640 px it reproduces the paper's column to within 0.06.
- The unused conv: the published VoVGSCSP defines a 3x3 conv it never calls. The paper
  counted it in params and gradients of the -gs rows; "params paper conv." adds it, the
  main params column does not (it cannot train: it gets no gradient).
- The -rep params: the paper lists 12.2 M for -rep but 10.2 M for -gs-rep. Both necks feed
  the head the same channels, so a head change must move both rows by the same amount; the
  pair cannot both hold. Our shared RepConv head removes the same parameters in both rows and
  its GFLOPs match the paper's.
"""


def paper_key(variant: str) -> str | None:
    """The Table II row a variant corresponds to (scale ignored), if any."""
    key = re.sub(r"^yolov8[nsmlx]-", "yolov8s-", variant)
    return key if key in TABLE2 else None


def write_reports(rows: list[dict], out: Path, cfg: AblationConfig) -> tuple[Path, Path, Path]:
    """Rewrite the three result files from ``rows`` (atomic: temp file, then rename)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(
        {k: round(v, 6) if isinstance(v, float) else v for k, v in r.items()} for r in rows
    )
    csv_path = write_text(out / "results.csv", buf.getvalue())
    md_path = write_text(out / "results.md", markdown(rows, cfg))
    png_path = plot_sweep(rows, out / "results.png", cfg.name)
    return csv_path, md_path, png_path


def markdown(rows: list[dict], cfg: AblationConfig) -> str:
    """The sweep's tables: Table II columns, the extra measurements, the paper beside ours."""
    t = cfg.train
    data = "embedded synthetic set" if cfg.data_path is None else str(cfg.data_path)
    first = rows[0] if rows else {"num_classes": "?", "git_sha": "?", "val_images": "?"}
    lines = [
        f"# Ablation sweep `{cfg.name}`",
        "",
        f"Data: {data} ({first['val_images']} val images). Recipe: "
        f"{t.epochs} epochs, batch {t.batch}, {t.imgsz} px, {t.optimizer} lr0 {t.lr0}, "
        f"seed {t.seed}. mAP: COCO (pycocotools) of the best EMA weights on the val split, "
        f"in %. GFLOPs, gradients and params at nc {first['num_classes']}, "
        f"{cfg.gflops_imgsz} px. Config hash {cfg.hash}, git {first['git_sha']}.",
        "",
        "## Table II columns",
        "",
        _table(
            ["Model", "mAP box", "mAP seg", "GFLOPs", "Gradients (M)", "Params (M)", "Epochs"],
            [
                [
                    r["variant"],
                    _pct(r["box_map50_95"]),
                    _pct(r["seg_map50_95"]),
                    f"{r['gflops']:.2f}",
                    f"{r['gradients'] / 1e6:.2f}",
                    f"{r['params'] / 1e6:.2f}",
                    str(r["epochs"]),
                ]
                for r in rows
            ],
        ),
        "",
        "## More measurements",
        "",
        _table(
            [
                "Model",
                "mAP50 box",
                "mAP50 seg",
                "best epoch",
                "fused params (M)",
                "GFLOPs paper conv.",
                f"ORT FP32 ms @{t.imgsz}",
                "train img/s",
                "spec hash",
            ],
            [
                [
                    r["variant"],
                    _pct(r["box_map50"]),
                    _pct(r["seg_map50"]),
                    str(r["best_epoch"]),
                    f"{r['fused_params'] / 1e6:.3f}",
                    f"{r['gflops_paper']:.2f}",
                    f"{r['latency_ms']:.1f}",
                    f"{r['train_img_s']:.1f}",
                    r["spec_hash"],
                ]
                for r in rows
            ],
        ),
    ]
    paired = [(r, TABLE2[k]) for r in rows if (k := paper_key(r["variant"])) is not None]
    if paired:
        lines += ["", *_paper_section(rows, paired)]
    return "\n".join(lines) + "\n"


def _paper_section(rows: list[dict], paired: list[tuple[dict, PaperRow]]) -> list[str]:
    base = next((r for r in rows if paper_key(r["variant"]) == "yolov8s-seg"), None)
    paper_base = TABLE2["yolov8s-seg"]
    out = [
        f"## The paper's Table II beside ours (paper: s scale, COCO-20, nc "
        f"{TABLE2_NUM_CLASSES}, {TABLE2_IMGSZ} px, 500 epochs)",
        "",
        _table(
            [
                "Model (ours → paper row)",
                "box ours",
                "box paper",
                "seg ours",
                "seg paper",
                "GFLOPs paper conv. ours",
                "GFLOPs paper",
                "Params paper conv. M ours",
                "Params M paper",
            ],
            [
                [
                    f"{r['variant']} → {paper_key(r['variant'])}",
                    _pct(r["box_map50_95"]),
                    f"{p.box_map:.1f}",
                    _pct(r["seg_map50_95"]),
                    f"{p.seg_map:.1f}",
                    f"{r['gflops_paper']:.2f}",
                    f"{p.gflops:.1f}",
                    f"{r['params_paper'] / 1e6:.2f}",
                    f"{p.params_m:.1f}",
                ]
                for r, p in paired
            ],
        ),
    ]
    if base is not None:
        out += [
            "",
            "Changes against each table's own baseline (mAP in points, cost in %):",
            "",
            _table(
                [
                    "Model",
                    "Δ box ours",
                    "Δ box paper",
                    "Δ seg ours",
                    "Δ seg paper",
                    "Δ GFLOPs ours",
                    "Δ GFLOPs paper",
                    "Δ params ours",
                    "Δ params paper",
                ],
                [
                    [
                        r["variant"],
                        _pts(r["box_map50_95"], base["box_map50_95"]),
                        f"{p.box_map - paper_base.box_map:+.1f}",
                        _pts(r["seg_map50_95"], base["seg_map50_95"]),
                        f"{p.seg_map - paper_base.seg_map:+.1f}",
                        _rel(r["gflops_paper"], base["gflops_paper"]),
                        _rel(p.gflops, paper_base.gflops),
                        _rel(r["params_paper"], base["params_paper"]),
                        _rel(p.params_m, paper_base.params_m),
                    ]
                    for r, p in paired
                ],
            ),
        ]
    return [*out, "", NOTES]


def plot_sweep(rows: list[dict], out: Path, title: str) -> Path:
    """mAP50-95 (seg filled, box hollow) against GFLOPs and against ORT latency → PNG."""
    fig = Figure(figsize=(11, 4.2))
    axes = fig.subplots(1, 2)
    xs = (("gflops", "GFLOPs @{}"), ("latency_ms", "onnxruntime FP32 latency (ms) @{}"))
    for ax, (key, label) in zip(axes, xs, strict=True):
        size = rows[0]["gflops_imgsz"] if key == "gflops" else rows[0]["latency_imgsz"]
        for i, r in enumerate(rows):
            color = f"C{i}"
            x = r[key]
            if not math.isnan(r["seg_map50_95"]):
                ax.scatter(x, 100 * r["seg_map50_95"], color=color, s=50, zorder=3)
            ax.scatter(x, 100 * r["box_map50_95"], facecolors="none", edgecolors=color, s=50)
            y = r["seg_map50_95"] if not math.isnan(r["seg_map50_95"]) else r["box_map50_95"]
            ax.annotate(
                r["variant"], (x, 100 * y), textcoords="offset points", xytext=(5, 5), fontsize=8
            )
        ax.set(xlabel=label.format(f"{size} px"), ylabel="mAP50-95 (%)", ylim=(0, None))
        ax.margins(x=0.3)  # room for the labels of the outermost points
        ax.grid(alpha=0.3)
    axes[0].set_title(f"{title}: filled = mask mAP, hollow = box mAP", fontsize=10)
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=110)
    return out


def _table(headers: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


def _pct(v: float) -> str:
    return "–" if math.isnan(v) else f"{100 * v:.1f}"


def _pts(v: float, base: float) -> str:
    return "–" if math.isnan(v) or math.isnan(base) else f"{100 * (v - base):+.1f}"


def _rel(v: float, base: float) -> str:
    return f"{100 * (v / base - 1):+.1f} %"
