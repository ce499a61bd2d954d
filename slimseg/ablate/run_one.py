"""One run of a sweep, safe to start again: the entry point every distributed backend calls.

    python -m slimseg.ablate.run_one OUT LABEL --stage train|measure \\
        --expect CONFIG_HASH VERSION GIT_SHA [--accelerator A --devices D] [--quiet]

Each call is idempotent. It reads the sweep from ``OUT/sweep.json`` (no file of the
driver's machine), checks that the stored config has the hash the driver planned and that
this node runs the driver's slimseg (a mismatch is an error, exit 2, never retried), then:

- ``train``: returns at once when the run has its row or its scores; otherwise takes the
  run's lease (:mod:`slimseg.ablate.lease`), trains from the last checkpoint (or from
  scratch), scores it and writes ``scores.json``;
- ``measure``: times the scored run (latency, a training burst) and writes ``row.json``.

The train stage runs as its own process: Lightning's DDP launcher starts the other ranks
by running this module again (``--devices 2`` or more). Exit codes: 0 done, 2 bad input
or version mismatch, 3 the lease went to a newer attempt (see :class:`LeaseLost`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import lightning as L

from slimseg.ablate.config import TrainerOptions, config_from_dict
from slimseg.ablate.lease import Lease, LeaseLost, acquire_lease, state_dir
from slimseg.ablate.rows import join_row, read_row, read_scores
from slimseg.ablate.sweep import (
    Run,
    SweepPlan,
    bench_frame,
    checkpoint_epochs,
    git_sha,
    score_columns,
    sweep_runs,
    timing_columns,
    train_run,
    trained_epochs,
)
from slimseg.data.config import load_data_config
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import write_json
from slimseg.version import __version__

logger = logging.getLogger(__name__)

EXIT_BAD_INPUT = 2
EXIT_LEASE_LOST = 3


class LeaseGuard(L.Callback):
    """Checks the run's lease (on the launching rank) before Lightning writes the epoch's
    checkpoint and before the validation writes the weights: callbacks run in list order,
    and Lightning moves its checkpoint callback to the end."""

    def __init__(self, lease: Lease) -> None:
        self.lease = lease

    def on_train_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if trainer.is_global_zero:
            self.lease.check(f"the checkpoint of epoch {trainer.current_epoch + 1}")

    def on_validation_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if trainer.is_global_zero and not trainer.sanity_checking:
            self.lease.check("the weights of the validation")


def check_version(version: str, sha: str) -> None:
    """SlimsegError unless this node runs slimseg ``version`` (the driver's). A different
    git commit is only logged (the row records the node's commit): a checkout shared by the
    nodes moves under a running sweep with every commit made to it, as it would under the
    local backend, and local changes (``-dirty``) say nothing about what differs."""
    mine = git_sha()
    if version != __version__:
        raise SlimsegError(
            f"this node runs slimseg {__version__} (git {mine}), the driver {version} (git "
            f"{sha}); install the same slimseg on every node of the cluster"
        )
    if "unknown" not in (sha, mine) and sha.removesuffix("-dirty") != mine.removesuffix("-dirty"):
        logger.warning(
            f"this node's slimseg checkout is at git {mine}, the driver's was at {sha} when "
            "the sweep started; the row records this node's commit"
        )


def load_plan(out: Path, config_hash: str) -> SweepPlan:
    """The sweep in ``out`` as the driver planned it (its data already in place)."""
    marker = Path(out) / "sweep.json"
    if not marker.is_file():
        raise SlimsegError(
            f"{marker}: not found on this node; the sweep folder must be on storage every "
            "node mounts at the same path"
        )
    stored = json.loads(marker.read_text())
    cfg = config_from_dict(stored["config"], config_hash, str(marker))
    data_yaml = cfg.data_path or Path(out) / "data" / "data.yaml"
    if not data_yaml.is_file():
        raise SlimsegError(
            f"{data_yaml}: not found on this node; the data must be on storage every node "
            "mounts at the same path"
        )
    data_cfg = load_data_config(data_yaml)
    specs = {a.name: a.model_spec().with_classes(len(data_cfg.names)) for a in cfg.variants}
    return SweepPlan(cfg, Path(out), data_yaml, data_cfg, specs, sweep_runs(cfg, Path(out)))


def train_stage(
    plan: SweepPlan,
    run: Run,
    trainer: TrainerOptions,
    progress: bool = False,
    log: Callable[[str], None] | None = None,
) -> dict:
    """``run`` trained and scored (``scores.json``); returns its row or its scores. A DDP
    worker rank trains and returns an empty dict."""
    log = log or logger.info
    cfg = plan.cfg
    done = read_row(run.dir, cfg.hash) or read_scores(run.dir, cfg.hash)
    if done is not None:
        log(f"{run.label}: scored earlier, kept")
        return done
    launcher = os.environ.get("LOCAL_RANK", "0") == "0" and os.environ.get("NODE_RANK", "0") == "0"
    callbacks: list[L.Callback] = []
    lease = None
    if launcher:
        ckpt = run.dir / "checkpoints" / "last.ckpt"
        epochs = trained_epochs(run.dir)
        if epochs < cfg.train.epochs:
            epochs = checkpoint_epochs(ckpt) if ckpt.is_file() else 0
        lease = acquire_lease(state_dir(plan.out, run.label), "train", resumed_from=epochs)
        callbacks.append(LeaseGuard(lease))
    try:
        if not train_run(plan, run, trainer, progress, log, run.label, callbacks):
            return {}
        assert lease is not None
        lease.check("scoring")
        scores = score_columns(plan, run, git_sha())
        lease.check("scores.json")
        write_json(run.dir / "scores.json", scores, indent=1)
    except LeaseLost:
        if lease is not None:
            lease.finish("lease lost")
        raise
    except BaseException as exc:
        if lease is not None:
            lease.finish(f"failed: {type(exc).__name__}")
        raise
    lease.finish("done")
    return scores


def measure_stage(
    plan: SweepPlan,
    run: Run,
    accelerator: str,
    steps: int = 20,
    warmup: int = 3,
    log: Callable[[str], None] | None = None,
) -> dict:
    """``run``'s timing measured here (latency at the bench sizes, a timed training burst
    of ``warmup + steps`` steps) and its ``row.json`` written; returns the row."""
    from slimseg.ablate.train_bench import timed_training

    log = log or logger.info
    cfg = plan.cfg
    row = read_row(run.dir, cfg.hash)
    if row is not None:
        return row
    scores = read_scores(run.dir, cfg.hash)
    if scores is None:
        raise SlimsegError(f"{run.dir}: not trained and scored yet (no scores.json)")
    lease = acquire_lease(state_dir(plan.out, run.label), "measure")
    try:
        spec = plan.specs[run.arm.name]
        train_cfg = dataclasses.replace(cfg.train, seed=run.seed)
        img_s = timed_training(spec, train_cfg, plan.data_yaml, accelerator, steps, warmup)
        lease.check("the ONNX exports")
        timing = timing_columns(plan, run, bench_frame(plan.data_cfg), img_s)
        row = join_row(scores, timing)
        lease.check("row.json")
        write_json(run.dir / "row.json", row, indent=1)
    except BaseException as exc:
        lease.finish("lease lost" if isinstance(exc, LeaseLost) else f"failed: {exc!r}"[:200])
        raise
    lease.finish("done")
    log(f"{run.label}: measured")
    return row


def main(argv: Sequence[str] | None = None) -> int:
    """Command line of the module (see its docstring)."""
    p = argparse.ArgumentParser(prog="python -m slimseg.ablate.run_one")
    p.add_argument("out", type=Path)
    p.add_argument("label")
    p.add_argument("--stage", choices=("train", "measure"), default="train")
    p.add_argument("--expect", nargs=3, metavar=("HASH", "VERSION", "SHA"), required=True)
    p.add_argument("--accelerator", default="auto")
    p.add_argument("--devices", default="1")
    p.add_argument("--steps", type=int, default=20, help="timed training steps (measure)")
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stdout)
    config_hash, version, sha = args.expect
    try:
        check_version(version, sha)
        plan = load_plan(args.out, config_hash)
        run = plan.run(args.label)
        if args.stage == "train":
            opts = TrainerOptions(args.accelerator, args.devices, 1)
            train_stage(plan, run, opts, progress=not args.quiet)
        else:
            measure_stage(plan, run, args.accelerator, args.steps)
    except LeaseLost as exc:
        print(f"run_one: {exc}", file=sys.stderr)
        return EXIT_LEASE_LOST
    except SlimsegError as exc:
        print(f"run_one: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return 0


if __name__ == "__main__":
    sys.exit(main())
