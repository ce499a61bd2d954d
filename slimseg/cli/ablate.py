"""``slimseg ablate``: the paper's Table II as one command (train, evaluate, measure, chart)."""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from slimseg.ablate.config import load_ablation_config
from slimseg.utils.shipped import shipped_names


def add_parser(sub: argparse._SubParsersAction) -> None:
    shipped = ", ".join(shipped_names("ablation"))
    p = sub.add_parser(
        "ablate",
        help="train and compare variants or spec overrides under one recipe and its seeds "
        "(the paper's Table II)",
        description="Train, evaluate (COCO box and mask mAP, plus the config's extra row "
        "metrics) and measure (params, gradients, GFLOPs, onnxruntime latency at each "
        "bench size, optionally NMS + mask post-processing, training images/s) every arm "
        "of a sweep config (a zoo variant, or a spec override on one) once per seed; write "
        "OUT/results.csv (one row per run), summary.csv (per arm: mean and spread, half the "
        "max-min range, over the seeds), results.md (with the paper's Table II beside the "
        "plain zoo arms) and results.png. Interrupted sweeps resume: rerun the same command. "
        f"Shipped configs (slimseg/configs/ablation): {shipped}; the config schema is in "
        "docs/ablation.md.",
    )
    p.add_argument("--config", required=True, help="sweep YAML, or the name of a shipped one")
    p.add_argument("--out", default=None, help="sweep folder (default runs/ablate/<name>)")
    p.add_argument("--data", default=None, help="data YAML replacing the config's data")
    p.add_argument("--accelerator", default=None, help="cpu | gpu | auto (default: config)")
    p.add_argument("--devices", default=None, help="e.g. 4 for DDP on 4 GPUs (default: config)")
    p.add_argument("--num-nodes", type=int, default=None)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from slimseg.ablate.sweep import run_sweep

    cfg = load_ablation_config(args.config, data=args.data)
    launch = {"accelerator": args.accelerator, "devices": args.devices}
    launch |= {"num_nodes": args.num_nodes}
    launch = {k: v for k, v in launch.items() if v is not None}
    if launch:
        cfg = dataclasses.replace(cfg, trainer=dataclasses.replace(cfg.trainer, **launch))
    out = Path(args.out) if args.out else Path("runs") / "ablate" / cfg.name
    start = time.perf_counter()
    seeds = ", ".join(map(str, cfg.run_seeds))
    runs = len(cfg.variants) * len(cfg.run_seeds)
    print(
        f"sweep {cfg.name}: {len(cfg.variants)} arms x seeds [{seeds}] = {runs} runs -> {out} "
        f"(config hash {cfg.hash})"
    )
    rows = run_sweep(cfg, out, progress=not args.quiet)
    minutes = (time.perf_counter() - start) / 60
    print(f"\n{len(rows)} runs in {minutes:.1f} min this run\n")
    print((out / "results.md").read_text())
    files = ", ".join(str(out / f) for f in ("results.csv", "summary.csv", "results.md"))
    print(f"results: {files}, {out / 'results.png'}")
    return 0
