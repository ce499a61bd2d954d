"""``slimseg demo``: the embedded end-to-end job — synth data → train on the CPU → val → plots."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from slimseg.data.coco import CocoDataset
from slimseg.data.config import load_data_config
from slimseg.data.dataset import ZooDataset
from slimseg.data.synth import generate
from slimseg.engine.config import load_train_config
from slimseg.engine.preview import prediction_grid
from slimseg.eval.coco_eval import format_metrics_table
from slimseg.eval.plots import plot_results
from slimseg.eval.semantic_metrics import format_semantic_table
from slimseg.eval.validation import validate_dataset
from slimseg.models.checkpoint import load_weights
from slimseg.utils.atomic import write_png

DEMO_RECIPE = "cpu-demo"  # slimseg/configs/train/cpu-demo.yaml


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="end to end on the embedded dataset: synth → train (CPU) → val → plots",
        description="Generate the synthetic RGB-D dataset (no download), train a small variant "
        "on the CPU with configs/train/cpu-demo.yaml, validate its EMA weights with COCO mAP, "
        "and write training curves and a prediction grid.",
    )
    p.add_argument("--out", default="runs/demo", help="demo folder (data/, train/, plots)")
    p.add_argument("--model", default="yolov8n-seg-gs-rep")
    p.add_argument("--epochs", type=int, default=None, help="default: the cpu-demo recipe's")
    p.add_argument("--imgsz", type=int, default=320)
    p.add_argument("--train-images", type=int, default=512)
    p.add_argument("--val-images", type=int, default=128)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from slimseg.engine.train import train

    start = time.perf_counter()
    out = Path(args.out)
    data_yaml = out / "data" / "data.yaml"
    if data_yaml.is_file():
        print(f"[1/4] reusing the synthetic dataset in {data_yaml.parent}")
    else:
        print(f"[1/4] generating {args.train_images}+{args.val_images} synthetic images")
        report = generate(
            out / "data",
            args.train_images,
            args.val_images,
            args.imgsz,
            args.seed,
            progress=not args.quiet,
        )
        print(report.summary())
    cfg = load_train_config(DEMO_RECIPE).override(
        epochs=args.epochs, imgsz=args.imgsz, seed=args.seed
    )
    print(f"[2/4] training {args.model} for {cfg.epochs} epochs at {cfg.imgsz} px on the CPU")
    _, run_dir = train(
        args.model, data_yaml, cfg, out / "train", progress=not args.quiet, accelerator="cpu"
    )
    print("[3/4] validating the best EMA weights, fused (as deployed)")
    model, info = load_weights(run_dir / "weights" / "best.pt", fused=True)
    val_set = ZooDataset(CocoDataset.from_config(load_data_config(data_yaml), "val"), cfg.imgsz)
    metrics, _ = validate_dataset(model, val_set, cfg.batch, progress=False)
    semantic = "miou" in metrics  # msnet-*: mIoU / MPA instead of COCO mAP
    print(format_semantic_table(metrics) if semantic else format_metrics_table(metrics, info.names))
    (out / "metrics.json").write_text(json.dumps(metrics, indent=1))
    print("[4/4] plots")
    curves = plot_results(run_dir / "results.csv", out / "results.png")
    grid = prediction_grid(model, val_set, info.names, count=8)
    preds = write_png(out / "predictions.png", grid)
    minutes = (time.perf_counter() - start) / 60
    if semantic:
        score = f"mIoU {metrics['miou']:.3f}, MPA {metrics['mpa']:.3f}"
    else:
        box, mask = metrics["box"], metrics.get("mask") or {}
        nan = float("nan")
        score = (
            f"box mAP50-95 {box['map50_95']:.3f} (mAP50 {box['map50']:.3f}), mask mAP50-95 "
            f"{mask.get('map50_95', nan):.3f} (mAP50 {mask.get('map50', nan):.3f})"
        )
    print(
        f"\ndone in {minutes:.1f} min: {score} at epoch {info.epoch + 1}\n"
        f"  weights     {run_dir / 'weights'}/best.pt, last.pt\n"
        f"  resume      {run_dir / 'checkpoints' / 'last.ckpt'}\n"
        f"  logs        {run_dir / 'tb'} (tensorboard --logdir {run_dir / 'tb'})\n"
        f"  plots       {curves}, {preds}\n"
        f"  metrics     {out / 'metrics.json'}"
    )
    return 0
