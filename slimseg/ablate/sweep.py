"""Run a sweep: train, evaluate and measure each variant under one recipe and seed.

Sweep folder::

    OUT/sweep.json                      the resolved config and its hash (a guard on resume)
    OUT/data/                           the embedded synthetic set (``data: synth``)
    OUT/variants/NAME/                  a ``slimseg train`` run folder, plus
        throughput.json                 images and seconds per training epoch
        model.onnx                      the fused FP32 export the latency was measured on
        row.json                        the finished row (present = variant done)
    OUT/results.csv, results.md, results.png    rewritten after every finished variant

Resume rule: a variant with ``row.json`` (of this config) is kept; one with a Lightning
``last.ckpt`` continues from it; one with neither starts over.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np

from slimseg.ablate.config import AblationConfig
from slimseg.ablate.report import write_reports
from slimseg.ablate.throughput import ThroughputMeter, images_per_second
from slimseg.data.coco import CocoDataset
from slimseg.data.config import load_data_config
from slimseg.data.dataset import YoloDataset
from slimseg.data.synth import generate
from slimseg.deploy.bench import median_ms
from slimseg.deploy.checkpoint import load_weights
from slimseg.deploy.onnx_export import export_onnx
from slimseg.deploy.ort_session import cpu_session
from slimseg.engine.evaluate import evaluate_dataset
from slimseg.errors import SlimsegError
from slimseg.eval.complexity import measure
from slimseg.models.registry import build_model
from slimseg.utils.atomic import write_json

ROW_VERSION = 1

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


def prepare_sweep_dir(cfg: AblationConfig, out: Path) -> None:
    """Create ``out`` or check that it holds a sweep of this very config."""
    marker = out / "sweep.json"
    if marker.is_file():
        stored = json.loads(marker.read_text())
        if stored.get("hash") != cfg.hash:
            raise SlimsegError(
                f"{out}: holds a sweep of another config (hash {stored.get('hash')} vs "
                f"{cfg.hash}); pass a different --out, or remove that folder to start over"
            )
        return
    out.mkdir(parents=True, exist_ok=True)
    write_json(marker, {"hash": cfg.hash, "config": cfg.to_dict(), "source": cfg.source})


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


def run_sweep(
    cfg: AblationConfig,
    out: Path,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> list[dict]:
    """Every variant of ``cfg`` trained, evaluated and measured; returns the rows in order.

    Progress lines go to ``log`` (default: this module's logger at INFO)."""
    log = log or logger.info
    from slimseg.engine.train import train  # Lightning import is slow: only when training

    if cfg.data_path is not None:
        load_data_config(cfg.data_path)  # a bad data config fails before anything is written
    prepare_sweep_dir(cfg, out)
    data_yaml = sweep_data(cfg, out, progress)
    data_cfg = load_data_config(data_yaml)
    sha = git_sha()
    rows: list[dict] = []
    for k, name in enumerate(cfg.variants, 1):
        vdir = out / "variants" / name
        row = read_row(vdir, cfg.hash)
        if row is not None:
            log(f"[{k}/{len(cfg.variants)}] {name}: done earlier, row kept")
            rows.append(row)
            continue
        epochs_done = trained_epochs(vdir)
        if epochs_done >= cfg.train.epochs:
            log(f"[{k}/{len(cfg.variants)}] {name}: trained earlier, measuring")
        else:
            ckpt = vdir / "checkpoints" / "last.ckpt"
            resume = ckpt.is_file()
            if not resume and vdir.exists():
                shutil.rmtree(vdir)  # killed before its first checkpoint: nothing to keep
            start = f"resuming after epoch {checkpoint_epochs(ckpt)}" if resume else "training"
            log(f"[{k}/{len(cfg.variants)}] {name}: {start} ({cfg.train.epochs} epochs)")
            train(
                name,
                data_yaml,
                cfg.train,
                vdir,
                resume=resume,
                devices=_devices(cfg.trainer.devices),
                num_nodes=cfg.trainer.num_nodes,
                accelerator=cfg.trainer.accelerator,
                progress=progress,
                callbacks=[ThroughputMeter(vdir / "throughput.json")],
            )
            if int(os.environ.get("LOCAL_RANK", "0")) or int(os.environ.get("NODE_RANK", "0")):
                continue  # DDP worker ranks train; the launching rank measures and writes
        row = measure_variant(cfg, name, vdir, data_yaml, data_cfg.names, sha, progress)
        write_json(vdir / "row.json", row, indent=1)
        rows.append(row)
        paths = write_reports(rows, out, cfg)
        log(f"[{k}/{len(cfg.variants)}] {name}: {_summary(row)} -> {paths[1]}")
    return rows


def read_row(vdir: Path, config_hash: str) -> dict | None:
    """The finished row of a variant folder, if it belongs to this config."""
    path = vdir / "row.json"
    if not path.is_file():
        return None
    row = json.loads(path.read_text())
    if row.get("config_hash") != config_hash or row.get("row_version") != ROW_VERSION:
        return None
    return row


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

    return int(torch.load(ckpt, map_location="cpu", weights_only=False)["epoch"]) + 1


def measure_variant(
    cfg: AblationConfig,
    name: str,
    vdir: Path,
    data_yaml: Path,
    names: list[str],
    sha: str,
    progress: bool = True,
) -> dict:
    """One row: COCO mAP of the best EMA weights on the val split (from the run's own
    validation, pycocotools), size and cost at ``cfg.gflops_imgsz``, onnxruntime FP32
    latency at the training imgsz, training throughput."""
    imgsz = cfg.train.imgsz
    model, info = load_weights(vdir / "weights" / "best.pt")
    val_set = YoloDataset(CocoDataset.from_config(load_data_config(data_yaml), "val"), imgsz)
    metrics = info.metrics  # the training run's COCO validation of exactly these weights
    if "box" not in metrics:  # weights written without a validation: score them now
        metrics, _ = evaluate_dataset(
            model.fuse(),
            val_set,
            cfg.train.batch,
            conf=cfg.train.conf,
            iou=cfg.train.iou,
            progress=progress,
        )
    size = measure(build_model(name, num_classes=len(names)), cfg.gflops_imgsz)
    onnx_path = vdir / "model.onnx"
    export_onnx(model, onnx_path, (imgsz, imgsz), names=names, mobility=info.mobility)
    session = cpu_session(onnx_path, cfg.bench.threads)
    feed = {"images": np.random.default_rng(0).random((1, 3, imgsz, imgsz), np.float32)}
    latency = median_ms(lambda: session.run(None, feed), cfg.bench.runs, cfg.bench.warmup)
    box, mask = metrics["box"], metrics.get("mask") or {}
    nan = float("nan")
    return {
        "variant": name,
        "epochs": cfg.train.epochs,
        "best_epoch": info.epoch + 1,
        "box_map50_95": box["map50_95"],
        "seg_map50_95": mask.get("map50_95", nan),
        "box_map50": box["map50"],
        "seg_map50": mask.get("map50", nan),
        "gflops": size.gflops,
        "gflops_paper": size.gflops_paper,
        "gflops_imgsz": cfg.gflops_imgsz,
        "gradients": size.gradients,
        "params": size.params,
        "params_paper": size.params_paper,
        "fused_params": size.fused_params,
        "latency_ms": latency,
        "latency_imgsz": imgsz,
        "train_img_s": images_per_second(vdir / "throughput.json"),
        "val_images": len(val_set),
        "num_classes": len(names),
        "spec_hash": info.spec.hash,
        "git_sha": sha,
        "seed": cfg.train.seed,
        "config_hash": cfg.hash,
        "row_version": ROW_VERSION,
    }


def _devices(value: str) -> int | str:
    return int(value) if value.isdigit() else value


def _summary(row: dict) -> str:
    return (
        f"box mAP50-95 {row['box_map50_95']:.3f}, seg {row['seg_map50_95']:.3f}, "
        f"{row['gflops']:.2f} GFLOPs, {row['latency_ms']:.1f} ms, {row['train_img_s']:.1f} img/s"
    )
