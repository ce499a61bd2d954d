"""``slimseg ablate``: the paper's Table II as one command (train, evaluate, measure, chart)."""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import TYPE_CHECKING

from slimseg.ablate.config import load_ablation_config
from slimseg.cli.arg_types import count, number
from slimseg.cli.commands import COMMAND_HELP
from slimseg.errors import SlimsegError
from slimseg.utils.extras import install_command
from slimseg.utils.shipped import shipped_names

if TYPE_CHECKING:
    from slimseg.ablate.ray_backend import RayOptions


def add_parser(sub: argparse._SubParsersAction) -> None:
    shipped = ", ".join(shipped_names("ablation"))
    p = sub.add_parser(
        "ablate",
        help=COMMAND_HELP["ablate"],
        description="Train, evaluate (COCO box and mask mAP, plus the config's extra row "
        "metrics) and measure (params, gradients, GFLOPs, onnxruntime latency at each "
        "bench size, optionally NMS + mask post-processing, training images/s) every arm "
        "of a sweep config (a zoo variant, or a spec override on one) once per seed; write "
        "OUT/results.csv (one row per run), summary.csv (per arm: mean and spread, half the "
        "max-min range, over the seeds), results.md (with the paper's Table II beside the "
        "plain zoo arms) and results.png. Interrupted sweeps resume: rerun the same command. "
        f"--backend ray spreads the runs over a Ray cluster ({install_command('ray')}). "
        f"Shipped configs (slimseg/configs/ablation): {shipped}; the config schema and the "
        "cluster setups are in docs/ablation.md.",
    )
    p.add_argument("--config", required=True, help="sweep YAML, or the name of a shipped one")
    p.add_argument("--out", default=None, help="sweep folder (default runs/ablate/<name>)")
    p.add_argument("--data", default=None, help="data YAML replacing the config's data")
    p.add_argument("--accelerator", default=None, help="cpu | gpu | auto (default: config)")
    p.add_argument("--devices", default=None, help="e.g. 4 for DDP on 4 GPUs (default: config)")
    p.add_argument("--num-nodes", type=count(1), default=None)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue the sweep in --out (an error when it holds none); a plain rerun "
        "resumes too, this only refuses to start a new one",
    )
    g = p.add_argument_group("distributed sweeps (docs/ablation.md)")
    g.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help="local: the runs one after another here (default); ray: one Ray task per run",
    )
    g.add_argument(
        "--address",
        default=None,
        help="ray: 'local' starts Ray on this machine for the sweep (default), 'auto' joins "
        "the running cluster, or HOST:PORT of its head",
    )
    g.add_argument(
        "--gpus-per-run",
        type=number(0),
        default=None,
        help="ray: GPUs per run, fractions pack runs onto a GPU, 2+ is DDP inside the run "
        "(default 1 when the cluster has GPUs, else 0)",
    )
    g.add_argument(
        "--cpus-per-run", type=number(0, open_low=True), default=None, help="ray: CPUs per run (1)"
    )
    g.add_argument(
        "--max-retries",
        type=int,
        default=None,
        help="ray: reruns of a run whose worker or node died (3); an error is not retried",
    )
    g.add_argument(
        "--throughput-steps",
        type=count(1),
        default=None,
        help="ray: training steps timed per run in the serial measure phase (20)",
    )
    p.set_defaults(run=run)


RAY_ONLY = ("address", "gpus_per_run", "cpus_per_run", "max_retries", "throughput_steps")


def run(args: argparse.Namespace) -> int:
    ray_opts = _ray_options(args)  # bad flags fail before the config is read
    cfg = load_ablation_config(args.config, data=args.data)
    launch = {"accelerator": args.accelerator, "devices": args.devices}
    launch |= {"num_nodes": args.num_nodes}
    launch = {k: v for k, v in launch.items() if v is not None}
    if launch:
        cfg = dataclasses.replace(cfg, trainer=dataclasses.replace(cfg.trainer, **launch))
    out = Path(args.out) if args.out else Path("runs") / "ablate" / cfg.name
    if args.resume and not (out / "sweep.json").is_file():
        raise SlimsegError(f"{out}: no sweep to resume (no sweep.json); drop --resume to start")
    start = time.perf_counter()
    seeds = ", ".join(map(str, cfg.run_seeds))
    runs = len(cfg.variants) * len(cfg.run_seeds)
    print(
        f"sweep {cfg.name}: {len(cfg.variants)} arms x seeds [{seeds}] = {runs} runs -> {out} "
        f"(config hash {cfg.hash})"
    )
    failures: list[str] = []
    if ray_opts is None:
        from slimseg.ablate.sweep import run_sweep

        rows = run_sweep(cfg, out, progress=not args.quiet)
    else:
        from slimseg.ablate.driver import run_sweep_ray

        rows, failures = run_sweep_ray(cfg, out, ray_opts)
    minutes = (time.perf_counter() - start) / 60
    print(f"\n{len(rows)} runs in {minutes:.1f} min this run\n")
    if (out / "results.md").is_file():
        print((out / "results.md").read_text())
        files = ", ".join(str(out / f) for f in ("results.csv", "summary.csv", "results.md"))
        print(f"results: {files}, {out / 'results.png'}")
    if failures:
        print(f"{len(failures)} run(s) failed (rerun the command to try them again):")
        print("\n".join(f"  {line}" for line in failures))
        return 1
    return 0


def _ray_options(args: argparse.Namespace) -> RayOptions | None:
    """The ray backend's options (None for the local backend); flags that do not fit the
    backend are an error naming the flag."""
    given = [f"--{k.replace('_', '-')}" for k in RAY_ONLY if getattr(args, k) is not None]
    if args.backend == "local":
        if given:
            raise SlimsegError(f"{', '.join(given)}: only with --backend ray")
        return None
    if args.devices is not None or (args.num_nodes or 1) > 1:
        raise SlimsegError(
            "--devices/--num-nodes: with --backend ray a run's devices come from "
            "--gpus-per-run (one node per run); for one run across nodes use --backend local "
            "under Slurm/torchrun (docs/ablation.md)"
        )
    gpus = args.gpus_per_run
    if gpus is not None and (gpus < 0 or (gpus > 1 and gpus != int(gpus))):
        raise SlimsegError(f"--gpus-per-run {gpus:g}: give 0, a fraction below 1, or a whole count")
    for flag, value, low in (
        ("--cpus-per-run", args.cpus_per_run, 0.01),
        ("--max-retries", args.max_retries, 0),
        ("--throughput-steps", args.throughput_steps, 1),
    ):
        if value is not None and value < low:
            raise SlimsegError(f"{flag} {value}: must be at least {low:g}")
    from slimseg.ablate.ray_backend import RayOptions

    opts = RayOptions(address=args.address or "local", gpus_per_run=gpus)
    changes = {
        "cpus_per_run": args.cpus_per_run,
        "max_retries": args.max_retries,
        "throughput_steps": args.throughput_steps,
    }
    return dataclasses.replace(opts, **{k: v for k, v in changes.items() if v is not None})
