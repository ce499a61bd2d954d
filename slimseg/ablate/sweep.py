"""Run a sweep: train, evaluate and measure each arm under one recipe, once per seed.

Sweep folder::

    OUT/sweep.json                      the resolved config and its hash (a guard on resume)
    OUT/data/                           the embedded synthetic set (``data: synth``)
    OUT/variants/NAME/                  a run (no ``seeds:``), or with ``seeds:``
    OUT/variants/NAME/seed-S/           one run per seed; each run folder is a
                                        ``slimseg train`` run folder, plus
        spec.yaml                       the arm's merged spec (arms with a spec override)
        throughput.json                 images and seconds per training epoch
        model.onnx, model-S.onnx        the fused FP32 exports the latency was measured on
        scores.json                     trained and scored, timing not measured yet (ray)
        row.json                        the finished row (present = run done)
    OUT/state/NAME[/seed-S]/            lease and attempts of the run (ray backend)
    OUT/results.csv, summary.csv, results.md, results.png   rebuilt from the rows on disk
                                        after every run, in plan order

Resume rule: a run with ``row.json`` (of this config) is kept; one with a Lightning
``last.ckpt`` continues from it; one with neither starts over. This module is the local
backend (runs one after another in this process) and the steps every backend shares.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import shutil
import subprocess
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from slimseg.ablate.arms import Arm
from slimseg.ablate.config import AblationConfig, TrainerOptions
from slimseg.ablate.latency import bench_latency
from slimseg.ablate.metrics import resolve_metrics, run_weights, score_run
from slimseg.ablate.report import ReportPaths, write_reports
from slimseg.ablate.rows import (
    FROM_EPOCHS,
    FROM_STEPS,
    ROW_VERSION,
    join_row,
    read_row,
    rows_on_disk,
)
from slimseg.ablate.throughput import ThroughputMeter, images_per_second
from slimseg.data.coco import CocoDataset
from slimseg.data.config import DataConfig, load_data_config
from slimseg.data.images import read_image_rgb8
from slimseg.data.synth import generate
from slimseg.errors import SlimsegError
from slimseg.eval.complexity import measure
from slimseg.models.checkpoint import load_weights
from slimseg.models.registry import build_from_spec
from slimseg.models.specs import ModelSpec
from slimseg.utils.atomic import add_to_manifest, write_json, write_text, write_yaml
from slimseg.utils.outputs import claim_folder

if TYPE_CHECKING:
    from lightning import Callback

logger = logging.getLogger(__name__)


def git_sha() -> str:
    """Short commit of the slimseg checkout (``-dirty`` with local changes), else ``unknown``."""
    repo = Path(__file__).resolve().parents[2]

    def git(*args: str) -> str:
        cmd = ["git", "-C", str(repo), *args]
        return subprocess.run(cmd, capture_output=True, text=True, check=True, timeout=10).stdout

    try:
        sha = git("rev-parse", "--short=10", "HEAD").strip()
        dirty = git("status", "--porcelain", "--untracked-files=no").strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return f"{sha}-dirty" if dirty else sha


SWEEP_ENTRIES = ("sweep.json", "data", "variants", "state", "results.csv", "summary.csv",
                 "results.md", "results.png")  # fmt: skip  # the layout above, top level


def prepare_sweep_dir(cfg: AblationConfig, out: Path) -> None:
    """Create ``out`` or check that it holds a sweep of this very config, and that this
    process can write in it (a clear error before any run starts). A folder holding anything
    a sweep did not write (a user's ``results.csv``) is refused; the manifest
    (:mod:`slimseg.utils.outputs`) lists :data:`SWEEP_ENTRIES` before any is written."""
    claim_folder(out, "--out", own=SWEEP_ENTRIES)
    marker = out / "sweep.json"
    if marker.is_file():
        stored = json.loads(marker.read_text())
        if stored.get("hash") != cfg.hash:
            raise SlimsegError(
                f"{out}: holds a sweep of another config (hash {stored.get('hash')} vs "
                f"{cfg.hash}); pass a different --out, or remove that folder to start over"
            )
        check_writable(out)
        return
    check_writable(out)
    add_to_manifest(out, "ablate", SWEEP_ENTRIES)
    write_json(marker, {"hash": cfg.hash, "config": cfg.to_dict(), "source": cfg.source})


def check_writable(out: Path) -> None:
    """Create ``out`` and write (then remove) a file in it; SlimsegError when it cannot."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = write_text(out / f".write-probe-{os.getpid()}", "ok")
        probe.unlink()
    except OSError as exc:
        raise SlimsegError(
            f"{out}: the sweep folder cannot be written ({exc.strerror or exc}); pass --out a "
            "folder this user can write (with --backend ray, one every node mounts)"
        ) from None


def sweep_data(cfg: AblationConfig, out: Path, progress: bool) -> Path:
    """The data YAML the sweep trains on (generating the embedded set once)."""
    if cfg.data_path is not None:
        return cfg.data_path
    data_yaml = out / "data" / "data.yaml"
    if not data_yaml.is_file():
        s = cfg.synth
        logger.info(f"generating the synthetic set: {s.train_images}+{s.val_images} images")
        generate(out / "data", s.train_images, s.val_images, s.imgsz, s.seed, progress=progress)
    return data_yaml


@dataclass(frozen=True)
class Run:
    """One (arm, seed) of a sweep and its run folder; ``label`` names it in logs."""

    arm: Arm
    seed: int
    dir: Path
    label: str


def sweep_runs(cfg: AblationConfig, out: Path) -> list[Run]:
    """Every run of ``cfg`` in order: ``variants/NAME`` without ``seeds:``,
    ``variants/NAME/seed-S`` with them, seed-major (every arm at the first seed, then every
    arm at the next), so a sweep cut short still compares all its arms."""
    base = out / "variants"
    if cfg.seeds is None:
        return [Run(a, cfg.train.seed, base / a.name, a.name) for a in cfg.variants]
    return [
        Run(a, s, base / a.name / f"seed-{s}", f"{a.name}/seed-{s}")
        for s in cfg.seeds
        for a in cfg.variants
    ]


@dataclass(frozen=True)
class SweepPlan:
    """A sweep ready to run: its folder prepared, its data generated, every arm's spec
    (class count set to the data's) and every run in plan order."""

    cfg: AblationConfig
    out: Path
    data_yaml: Path
    data_cfg: DataConfig
    specs: dict[str, ModelSpec]
    runs: list[Run]

    def run(self, label: str) -> Run:
        """The run called ``label`` (``NAME`` or ``NAME/seed-S``)."""
        for run in self.runs:
            if run.label == label:
                return run
        raise SlimsegError(f"{self.out}: no run {label!r} in this sweep")

    def rows(self) -> list[dict]:
        """The rows on disk in plan order (:func:`~slimseg.ablate.rows.rows_on_disk`)."""
        dirs = [r.dir for r in self.runs]
        return rows_on_disk(dirs, self.cfg.hash, self.cfg.bench_sizes, self.cfg.bench.masks)

    def write_reports(self) -> ReportPaths | None:
        """Rebuild the reports from the rows on disk (None while no run has a row)."""
        rows = self.rows()
        return write_reports(rows, self.out, self.cfg) if rows else None


def plan_sweep(cfg: AblationConfig, out: Path, progress: bool = True) -> SweepPlan:
    """Check the data config, prepare ``out`` (or check it holds this sweep), generate the
    embedded set once; nothing is trained."""
    if cfg.data_path is not None:
        load_data_config(cfg.data_path)  # a bad data config fails before anything is written
    prepare_sweep_dir(cfg, out)
    data_yaml = sweep_data(cfg, out, progress)
    data_cfg = load_data_config(data_yaml)
    specs = {a.name: a.model_spec().with_classes(len(data_cfg.names)) for a in cfg.variants}
    return SweepPlan(cfg, out, data_yaml, data_cfg, specs, sweep_runs(cfg, out))


def run_sweep(
    cfg: AblationConfig,
    out: Path,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> list[dict]:
    """Every run of ``cfg`` trained, evaluated and measured here, one after the other (the
    local backend); returns the rows in plan order.

    Progress lines go to ``log`` (default: this module's logger at INFO)."""
    log = log or logger.info
    plan = plan_sweep(cfg, out, progress)
    frame = bench_frame(plan.data_cfg)
    sha = git_sha()
    runs = plan.runs
    for k, run in enumerate(runs, 1):
        tag = f"[{k}/{len(runs)}] {run.label}"
        if read_row(run.dir, cfg.hash) is not None:
            log(f"{tag}: done earlier, row kept")
            continue
        if not train_run(plan, run, cfg.trainer, progress, log, tag):
            continue  # DDP worker ranks train; the launching rank measures and writes
        scores = score_columns(plan, run, sha)
        row = join_row(scores, timing_columns(plan, run, frame))
        write_json(run.dir / "row.json", row, indent=1)
        paths = plan.write_reports()
        log(f"{tag}: {_summary(row)} -> {paths.md if paths else out}")
    return plan.rows()


def train_run(
    plan: SweepPlan,
    run: Run,
    trainer: TrainerOptions,
    progress: bool,
    log: Callable[[str], None],
    tag: str,
    callbacks: Sequence[Callback] = (),
) -> bool:
    """Train ``run`` to the recipe's last epoch: nothing when ``weights/last.pt`` has them
    all, from ``checkpoints/last.ckpt`` when there is one, else from scratch (a folder
    without a checkpoint is emptied first). ``callbacks`` go before the run's own. Returns
    False in a DDP worker rank (the launching rank scores and measures)."""
    from slimseg.engine.train import train  # Lightning import is slow: only when training

    rdir, cfg = run.dir, plan.cfg
    train_cfg = dataclasses.replace(cfg.train, seed=run.seed)
    if trained_epochs(rdir) >= train_cfg.epochs:
        log(f"{tag}: trained earlier, measuring")
        return True
    ckpt = rdir / "checkpoints" / "last.ckpt"
    resume = ckpt.is_file()
    launcher = not (int(os.environ.get("LOCAL_RANK", "0")) or int(os.environ.get("NODE_RANK", "0")))
    if not resume and rdir.exists() and launcher:
        # killed before its first checkpoint: nothing to keep (DDP worker ranks start after
        # the launching rank has begun this run's folder, and must leave it alone)
        shutil.rmtree(rdir)
    start = f"resuming after epoch {checkpoint_epochs(ckpt)}" if resume else "training"
    log(f"{tag}: {start} ({train_cfg.epochs} epochs, seed {run.seed})")
    spec = plan.specs[run.arm.name]
    train(
        run.arm.name if run.arm.plain else spec,
        plan.data_yaml,
        train_cfg,
        rdir,
        resume=resume,
        devices=_devices(trainer.devices),
        num_nodes=trainer.num_nodes,
        accelerator=trainer.accelerator,
        progress=progress,
        callbacks=[*callbacks, ThroughputMeter(rdir / "throughput.json")],
    )
    return launcher


def bench_frame(data_cfg: DataConfig) -> np.ndarray:
    """The val frame the latency bench runs on (the split's first image), ``uint8 [h, w, 3]``."""
    val = CocoDataset.from_config(data_cfg, "val")
    if not len(val):
        raise SlimsegError(f"{data_cfg.source}: the val split has no images to score or time")
    image, _ = read_image_rgb8(val.image_path(0))
    return image


def trained_epochs(vdir: Path) -> int:
    """Epochs whose weights ``weights/last.pt`` holds (0 when there is none)."""
    path = vdir / "weights" / "last.pt"
    if not path.is_file():
        return 0
    _, info = load_weights(path)
    return info.epoch + 1


def checkpoint_epochs(ckpt: Path) -> int:
    """Epochs a Lightning ``last.ckpt`` has finished."""
    import torch

    return int(torch.load(ckpt, map_location="cpu", weights_only=True)["epoch"]) + 1


def score_columns(plan: SweepPlan, run: Run, sha: str) -> dict:
    """The machine-independent part of ``run``'s row: the metrics of ``cfg.metrics`` (COCO
    mAP of the best EMA weights on the val split first), size and cost of the arm's spec at
    ``cfg.gflops_imgsz``, and the run's identity. Writes the spec of an override arm to
    ``spec.yaml`` (loadable by ``slimseg train --model``)."""
    cfg, spec, data_cfg = plan.cfg, plan.specs[run.arm.name], plan.data_cfg
    if not run.arm.plain:
        write_yaml(run.dir / "spec.yaml", spec.to_dict())
    _, info = run_weights(run.dir)
    scores = score_run(resolve_metrics(cfg.metrics, cfg.source), run.dir, spec, data_cfg)
    size = measure(build_from_spec(spec), cfg.gflops_imgsz)
    return {
        "variant": run.arm.name,
        "model": run.arm.model,
        "epochs": cfg.train.epochs,
        "best_epoch": info.epoch + 1,
        **scores,
        "gflops": size.gflops,
        "gflops_paper": size.gflops_paper,
        "gflops_imgsz": cfg.gflops_imgsz,
        "gradients": size.gradients,
        "params": size.params,
        "params_paper": size.params_paper,
        "fused_params": size.fused_params,
        "val_images": len(CocoDataset.from_config(data_cfg, "val")),
        "num_classes": len(data_cfg.names),
        "spec_hash": info.spec.hash,
        "git_sha": sha,
        "seed": run.seed,
        "config_hash": cfg.hash,
        "row_version": ROW_VERSION,
    }


def timing_columns(
    plan: SweepPlan, run: Run, frame: np.ndarray, train_img_s: float | None = None
) -> dict:
    """The machine-dependent part of ``run``'s row: onnxruntime latency (and
    post-processing) of the best weights at the bench sizes on ``frame``, and training
    images/s: ``train_img_s`` when given (timed apart), else the run's training epochs."""
    cfg = plan.cfg
    model, info = run_weights(run.dir)
    latency = bench_latency(model, info, run.dir, cfg.train.imgsz, cfg.bench, frame)
    first = cfg.bench_sizes[0]
    timed = train_img_s is not None
    return {
        "latency_ms": latency[f"ms_net@{first}"],
        "latency_imgsz": first,
        **latency,
        "train_img_s": train_img_s if timed else images_per_second(run.dir / "throughput.json"),
        "train_img_s_from": FROM_STEPS if timed else FROM_EPOCHS,
    }


def _devices(value: str) -> int | str:
    return int(value) if value.isdigit() else value


def _summary(row: dict) -> str:
    return (
        f"box mAP50-95 {row['box_map50_95']:.3f}, seg {row['seg_map50_95']:.3f}, "
        f"{row['gflops']:.2f} GFLOPs, {row['latency_ms']:.1f} ms, {row['train_img_s']:.1f} img/s"
    )
