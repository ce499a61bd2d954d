"""Training throughput timed apart from the run: a short burst of the run's own training loop.

When runs train side by side (the ray backend packs several onto a node or a GPU), the
images/s their epochs reach says more about their neighbours than about the arm. The
serial measure phase therefore trains each arm again for ``warmup + steps`` optimiser
steps, alone on its machine, with the recipe's batch, image size, loader and precision,
and times the last ``steps`` (data loading and the optimiser step included, as in
:class:`~slimseg.ablate.throughput.ThroughputMeter`). The weights are a fresh
initialisation: the time of a step does not depend on them.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
import warnings
from pathlib import Path

import lightning as L
import torch

from slimseg.data.augment import AugmentConfig
from slimseg.data.config import load_data_config
from slimseg.data.datamodule import SegDataModule
from slimseg.engine.config import TrainConfig
from slimseg.engine.module import ZooModule
from slimseg.engine.precision import resolve_precision
from slimseg.engine.train import QUIET_WARNINGS
from slimseg.losses.instance_mask import target_mask_ratio
from slimseg.models.specs import ModelSpec
from slimseg.utils.threads import torch_threads


class _StepClock(L.Callback):
    """Images and seconds of the training steps after the first ``warmup``."""

    def __init__(self, warmup: int) -> None:
        self.warmup = warmup
        self.step = 0
        self.images = 0
        self.start = self.end = 0.0

    def _now(self, module: L.LightningModule) -> float:
        if module.device.type == "cuda":
            torch.cuda.synchronize(module.device)
        return time.perf_counter()

    def on_train_batch_start(
        self, trainer: L.Trainer, module: L.LightningModule, batch: dict, i: int
    ) -> None:
        if self.step == self.warmup:
            self.start = self._now(module)

    def on_train_batch_end(
        self, trainer: L.Trainer, module: L.LightningModule, outputs: object, batch: dict, i: int
    ) -> None:
        if self.step >= self.warmup:
            self.images += int(batch["images"].shape[0])
            self.end = self._now(module)
        self.step += 1


def timed_training(
    spec: ModelSpec,
    cfg: TrainConfig,
    data_yaml: Path,
    accelerator: str,
    steps: int = 20,
    warmup: int = 3,
) -> float:
    """Training images/s of ``spec`` under recipe ``cfg`` over ``steps`` steps after
    ``warmup`` (one device, epochs as many as the steps need)."""
    data_cfg = load_data_config(data_yaml)
    module = ZooModule(
        spec.to_dict(), dataclasses.asdict(cfg), list(data_cfg.names), list(data_cfg.mobility)
    )
    dm = SegDataModule(
        data_cfg,
        cfg.imgsz,
        cfg.batch,
        cfg.workers,
        AugmentConfig(),
        cfg.seed,
        mask_ratio=target_mask_ratio(spec),
        semantic=module.semantic,
        mosaic_epochs=cfg.epochs - cfg.close_mosaic,
    )
    use_gpu = accelerator in ("gpu", "cuda") or (
        accelerator == "auto" and torch.cuda.is_available()
    )
    clock = _StepClock(warmup)
    with tempfile.TemporaryDirectory(prefix="slimseg-train-bench-") as root:
        trainer = L.Trainer(
            max_steps=warmup + steps,
            max_epochs=-1,
            accelerator=accelerator,
            devices=1,
            precision=resolve_precision("auto", cfg.amp, use_gpu),
            gradient_clip_val=cfg.grad_clip or None,
            limit_val_batches=0,
            num_sanity_val_steps=0,
            logger=False,
            enable_checkpointing=False,
            enable_progress_bar=False,
            enable_model_summary=False,
            default_root_dir=root,
            callbacks=[clock],
        )
        with warnings.catch_warnings(), torch_threads(cfg.threads):
            for message in (*QUIET_WARNINGS, r".*max_epochs=-1.*", r".*limit_val_batches=0.*"):
                warnings.filterwarnings("ignore", message=message)
            trainer.fit(module, datamodule=dm)
    seconds = clock.end - clock.start
    return clock.images / seconds if clock.images and seconds > 0 else float("nan")
