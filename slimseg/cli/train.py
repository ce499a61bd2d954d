"""``slimseg train``: train a zoo variant on a dataset config (CPU, one GPU, DDP)."""

from __future__ import annotations

import argparse
from pathlib import Path

from slimseg.cli.arg_types import count, multiple_of, number, threads
from slimseg.cli.commands import COMMAND_HELP
from slimseg.data.augment import load_augment_config
from slimseg.data.config import SPLITS, load_data_config
from slimseg.engine.config import load_train_config
from slimseg.engine.precision import PRECISIONS
from slimseg.eval.coco_eval import format_metrics_table
from slimseg.eval.semantic_metrics import format_semantic_table


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help=COMMAND_HELP["train"],
        description="Train a zoo variant on a COCO-format dataset config. Writes "
        "OUT/weights/{last,best}.pt (EMA weights), OUT/checkpoints/last.ckpt (for --resume), "
        "OUT/results.csv and TensorBoard logs in OUT/tb.",
    )
    p.add_argument("--model", required=True, help="variant name (slimseg info) or spec YAML")
    p.add_argument("--data", required=True, help="dataset config YAML")
    p.add_argument(
        "--config",
        default=None,
        help="recipe YAML, or a shipped name: default, cpu-demo, msnet-cpu",
    )
    p.add_argument(
        "--augment",
        default=None,
        help="augmentation YAML, or the shipped 'augment' (the default values)",
    )
    p.add_argument("--imgsz", type=multiple_of(), default=None)
    p.add_argument("--epochs", type=count(1), default=None)
    p.add_argument("--batch", type=count(1), default=None)
    p.add_argument("--lr0", type=number(0, open_low=True), default=None)
    p.add_argument("--workers", type=count(0), default=None)
    p.add_argument("--seed", type=count(0), default=None)
    p.add_argument(
        "--threads", type=threads(), default=None, help="torch CPU threads (0 = all cores)"
    )
    p.add_argument(
        "--precision",
        choices=PRECISIONS,
        default="auto",
        help="auto: 16-mixed on a GPU when the recipe's amp is on, else 32-true",
    )
    p.add_argument("--out", default=None, help="run folder (default runs/<model>)")
    p.add_argument("--resume", action="store_true", help="continue OUT from checkpoints/last.ckpt")
    p.add_argument("--weights", default=None, help="initial weights (.pt or .ckpt); shapes matched")
    p.add_argument(
        "--freeze",
        default="",
        help="comma list of top-level parts kept fixed, e.g. backbone,neck,detect to train "
        "only the mask branch of a trained model (with --weights)",
    )
    p.add_argument("--accelerator", default="auto", help="cpu | gpu | auto")
    p.add_argument("--devices", default="auto", help="number of devices, e.g. 2 (DDP)")
    p.add_argument("--num-nodes", type=count(1), default=1)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from slimseg.engine.train import train

    data = load_data_config(args.data)
    for split in SPLITS:  # before any model or run folder: a sequences-only yaml has neither
        data.split(split)
    cfg = load_train_config(args.config).override(
        imgsz=args.imgsz,
        epochs=args.epochs,
        batch=args.batch,
        lr0=args.lr0,
        workers=args.workers,
        seed=args.seed,
        threads=args.threads,
    )
    out = Path(args.out) if args.out else Path("runs") / Path(args.model).stem
    devices = int(args.devices) if str(args.devices).isdigit() else args.devices
    module, out = train(
        args.model,
        args.data,
        cfg,
        out,
        resume=args.resume,
        devices=devices,
        num_nodes=args.num_nodes,
        accelerator=args.accelerator,
        weights=args.weights,
        freeze=tuple(n.strip() for n in args.freeze.split(",") if n.strip()),
        augment=load_augment_config(args.augment),
        progress=not args.quiet,
        precision=args.precision,
    )
    if module.trainer.is_global_zero:
        if module.last_metrics and "miou" in module.last_metrics:
            print(format_semantic_table(module.last_metrics))
        elif module.last_metrics:
            print(format_metrics_table(module.last_metrics, module.names))
        print(f"run folder: {out}  (weights/best.pt, weights/last.pt, results.csv, tb/)")
    return 0
