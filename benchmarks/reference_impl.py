"""The reference YOLOv8 implementation, driven on slimseg's images (benchmarks only).

The reference package is an optional, benchmark-only dependency (AGPL): nothing in the
``slimseg`` package imports it. :func:`load` returns ``None`` when it is not installed, and
the benchmarks then print slimseg's figures alone (``pip install --no-deps ultralytics`` plus
the few small packages it needs to import; it must not replace torch or OpenCV).

Models are built from the YAML shipped with the package (no weights, no download): the
environment is set offline before the import.
"""

from __future__ import annotations

import importlib
import os
import time
from pathlib import Path
from types import ModuleType
from typing import Any

import cv2
import numpy as np
import torch

from slimseg.data.coco import CocoDataset
from slimseg.data.config import load_data_config


def load() -> ModuleType | None:
    """The reference package, offline; ``None`` (with a printed line) when absent."""
    os.environ.setdefault("YOLO_OFFLINE", "1")
    os.environ.setdefault("YOLO_VERBOSE", "False")
    try:
        module = importlib.import_module("ultralytics")
    except ImportError as exc:
        print(f"reference implementation not installed ({exc}): slimseg figures only")
        return None
    return module


def _polygon(mask: np.ndarray) -> np.ndarray | None:
    """Largest outer contour of a ``uint8 [H, W]`` mask as ``float [K, 2]`` pixels."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return None
    c = max(contours, key=cv2.contourArea).reshape(-1, 2).astype(np.float64)
    return c if len(c) >= 3 else None


def export_yolo_split(dataset: CocoDataset, out: Path) -> Path:
    """Write ``out/images`` (links to the source images) and ``out/labels`` (one polygon per
    instance, normalised ``class x y ...``): the reference's own label layout."""
    (out / "images").mkdir(parents=True, exist_ok=True)
    (out / "labels").mkdir(parents=True, exist_ok=True)
    for i in range(len(dataset)):
        sample = dataset[i]
        src = Path(sample.path)
        link = out / "images" / src.name
        if not link.exists():
            link.symlink_to(src.resolve())
        h, w = sample.image.shape[:2]
        lines = []
        for mask, cls in zip(sample.masks, sample.classes, strict=True):
            poly = _polygon(mask)
            if poly is None:
                continue
            xy = (poly / (w, h)).reshape(-1)
            lines.append(" ".join([str(int(cls)), *(f"{v:.6f}" for v in xy)]))
        (out / "labels" / f"{src.stem}.txt").write_text("\n".join(lines) + "\n")
    return out / "images"


def export_yolo_data(data_yaml: Path, out: Path) -> Path:
    """A reference data YAML over the same images as slimseg's ``data_yaml``."""
    cfg = load_data_config(data_yaml)
    lines = [f"path: {out}"]
    for split in ("train", "val"):
        s = cfg.split(split)
        images = export_yolo_split(
            CocoDataset(s.images, s.annotations, names=cfg.names), out / split
        )
        lines.append(f"{split}: {images}")
    lines.append("names: {" + ", ".join(f"{k}: '{n}'" for k, n in enumerate(cfg.names)) + "}")
    path = out / "data.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


class StepClock:
    """End time of every training batch; images/s over the batches after ``warmup``."""

    def __init__(self, batch: int, warmup: int) -> None:
        self.batch, self.warmup = batch, warmup
        self.ends: list[float] = []
        self.threads: set[int] = set()

    def tick(self) -> None:
        self.ends.append(time.perf_counter())
        self.threads.add(torch.get_num_threads())

    def images_per_s(self) -> float:
        if len(self.ends) <= self.warmup + 1:
            raise RuntimeError(f"only {len(self.ends)} batches: need more than {self.warmup + 1}")
        steps = len(self.ends) - 1 - self.warmup
        return steps * self.batch / (self.ends[-1] - self.ends[self.warmup])


def train_epoch(
    ref: ModuleType,
    data_yaml: Path,
    model: str,
    imgsz: int,
    batch: int,
    threads: int,
    warmup: int,
    project: Path,
) -> StepClock:
    """One epoch of the reference trainer (CPU, loader in the main process, mosaic on,
    one optimizer step per batch: ``nbs = batch``); returns the batch clock."""
    clock = StepClock(batch, warmup)

    def pin_threads(_trainer: Any) -> None:
        torch.set_num_threads(threads)  # the reference drops to 1 thread on 2 cores

    yolo = ref.YOLO(f"{model}.yaml")
    yolo.add_callback("on_train_start", pin_threads)
    yolo.add_callback("on_train_epoch_start", pin_threads)
    yolo.add_callback("on_train_batch_end", lambda _t: clock.tick())
    yolo.train(
        data=str(data_yaml),
        epochs=1,
        imgsz=imgsz,
        batch=batch,
        workers=0,
        device="cpu",
        nbs=batch,
        close_mosaic=0,
        val=False,
        plots=False,
        save=False,
        amp=False,
        project=str(project),
        name="ref",
        exist_ok=True,
        verbose=False,
        seed=0,
        deterministic=False,
    )
    return clock


def pipeline_rate(dataset: Any, collate: Any, batch: int, warmup: int, images: int) -> float:
    """Images/s of ``collate([dataset[i] ...])`` over ``images`` samples in order, after
    ``warmup`` untimed ones (they fill the mosaic partner buffers; a real epoch is much
    longer than that, so its rate is the steady state)."""
    n = len(dataset)
    for s in range(0, warmup, batch):
        collate([dataset[(s + k) % n] for k in range(batch)])
    start = time.perf_counter()
    for s in range(warmup, warmup + images, batch):
        collate([dataset[(s + k) % n] for k in range(batch)])
    return images / (time.perf_counter() - start)


def loader_rate(
    ref: ModuleType, data_yaml: Path, imgsz: int, batch: int, warmup: int, images: int
) -> float:
    """Images/s of the reference's training dataset + collate in this process (one
    worker's pipeline: decode, mosaic, affine, HSV, flip, formatting, collation), with its
    default ``cache=False`` (every sample decodes its image)."""
    from ultralytics.cfg import get_cfg
    from ultralytics.data import build_yolo_dataset
    from ultralytics.data.utils import check_det_dataset

    cfg = get_cfg(overrides={"imgsz": imgsz, "task": "segment", "close_mosaic": 0})
    data = check_det_dataset(str(data_yaml))
    dataset = build_yolo_dataset(cfg, data["train"], batch, data, mode="train", stride=32)
    return pipeline_rate(dataset, dataset.collate_fn, batch, warmup, images)
