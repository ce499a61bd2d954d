"""A thin LightningModule around any zoo model: loss, optimizer groups, warmup, EMA, COCO val."""

from __future__ import annotations

from typing import Any

import lightning as L
import torch
import torch.distributed as dist
from lightning.pytorch.loggers import TensorBoardLogger
from torch import nn

from slimseg.data.collate import network_input
from slimseg.engine.config import TrainConfig
from slimseg.engine.criterion import build_criterion
from slimseg.engine.ema import ModelEMA
from slimseg.engine.preview import prediction_grid
from slimseg.engine.schedule import lr_factor, warmup_values
from slimseg.errors import SlimsegError
from slimseg.eval.coco_eval import CocoEvaluator
from slimseg.eval.semantic_metrics import ConfusionMatrix
from slimseg.eval.validation import detect_batch, iou_types_for, is_semantic, semantic_batch
from slimseg.models.registry import build_from_spec
from slimseg.models.specs import ModelSpec, spec_from_mapping
from slimseg.utils.full_precision import full_precision
from slimseg.utils.strict_dataclass import dataclass_from_mapping


class NonFiniteLossError(SlimsegError):
    """The loss became NaN/inf; training stops and the last good checkpoint is kept."""


def parameter_groups(model: nn.Module, weight_decay: float) -> list[dict]:
    """Three groups: conv/linear weights (decayed), norm weights and biases (not decayed)."""
    decay, norm, bias = [], [], []
    for module in model.modules():
        for name, p in module.named_parameters(recurse=False):
            if not p.requires_grad:
                continue
            if name == "bias":
                bias.append(p)
            elif isinstance(module, (nn.BatchNorm2d, nn.GroupNorm, nn.LayerNorm)) or p.ndim < 2:
                norm.append(p)
            else:
                decay.append(p)
    return [
        {"params": decay, "weight_decay": weight_decay, "group": "weights"},
        {"params": norm, "weight_decay": 0.0, "group": "norm"},
        {"params": bias, "weight_decay": 0.0, "group": "bias"},
    ]


def _distributed() -> bool:
    return dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1


def nonfinite_ranks(loss: torch.Tensor) -> list[int]:
    """The ranks whose ``loss`` (scalar) is NaN/inf, the same list on every rank (one
    all-reduce under DDP, collective: every rank must call it at the same step), so all ranks
    take the same decision; ``[0]`` or ``[]`` in a single process."""
    if not _distributed():
        return [] if bool(torch.isfinite(loss)) else [0]
    flags = torch.zeros(dist.get_world_size(), device=loss.device)
    flags[dist.get_rank()] = (~torch.isfinite(loss.detach())).float()
    dist.all_reduce(flags)
    return flags.nonzero().flatten().tolist()


class ZooModule(L.LightningModule):
    """Trains ``build_from_spec(spec)``; validates (and checkpoints) its EMA weights.

    Validation: COCO box/mask mAP (``val/box_map50_95``, ...) for detectors and instance
    segmenters; mIoU and MPA from a confusion matrix over the val set (``val/miou``,
    ``val/mpa``) for semantic models (MSNET).

    ``spec`` and ``train`` are plain dicts (so checkpoints hold them as hyper-parameters);
    ``names``/``mobility`` describe the classes.
    """

    def __init__(
        self,
        spec: dict,
        train: dict,
        names: list[str],
        mobility: list[float] | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.spec: ModelSpec = spec_from_mapping(ModelSpec, spec, "spec")
        self.cfg: TrainConfig = dataclass_from_mapping(TrainConfig, train, "train")
        self.names, self.mobility = list(names), list(mobility or [])
        self.model = build_from_spec(self.spec)
        self.criterion = build_criterion(self.model)
        self.ema = ModelEMA(self.model, self.cfg.ema_decay) if self.cfg.ema else None
        self.evaluator: CocoEvaluator | None = None
        self._val_results: list[tuple[list[int], list[Any]]] = []
        self.semantic = is_semantic(self.model)
        self.last_metrics: dict = {}
        self.validated_epoch = -1  # the training epoch the last validation scored

    # ------------------------------------------------------------------ training
    def forward(self, images: torch.Tensor) -> Any:
        return self.model(images)

    def configure_optimizers(self) -> torch.optim.Optimizer:
        groups = parameter_groups(self.model, self.cfg.weight_decay)
        if self.cfg.optimizer == "sgd":
            return torch.optim.SGD(
                groups, lr=self.cfg.lr0, momentum=self.cfg.momentum, nesterov=True
            )
        return torch.optim.AdamW(groups, lr=self.cfg.lr0, betas=(self.cfg.momentum, 0.999))

    def on_fit_start(self) -> None:
        if self.ema is not None:
            self.ema.module.to(self.device)

    def on_train_batch_start(self, batch: dict, batch_idx: int) -> None:
        nb = max(self.trainer.num_training_batches, 1)
        step = self.global_step
        warmup = max(round(self.cfg.warmup_epochs * nb), 100) if self.cfg.warmup_epochs else 0
        target = self.cfg.lr0 * lr_factor(self.current_epoch + batch_idx / nb, self.cfg)
        for group in self.trainer.optimizers[0].param_groups:
            lr, momentum = warmup_values(step, warmup, target, group["group"] == "bias", self.cfg)
            group["lr"] = lr
            if momentum is not None:
                if "betas" in group:
                    group["betas"] = (momentum, group["betas"][1])
                else:
                    group["momentum"] = momentum

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        loss, terms = self.criterion(self.model(network_input(batch["images"])), batch)
        bad = nonfinite_ranks(loss)
        if bad:  # every rank got the same list: all stop here, none waits in a collective
            raise NonFiniteLossError(self._nonfinite_message(loss, terms, bad))
        bs = batch["images"].shape[0]
        self.log("loss", loss / bs, prog_bar=True, on_epoch=False, logger=False, batch_size=bs)
        for k, v in terms.items():  # averaged over ranks, not rank 0's shard alone
            self.log(f"train/{k}", v, on_step=False, on_epoch=True, batch_size=bs, sync_dist=True)
        self.log("lr", self.trainer.optimizers[0].param_groups[0]["lr"], batch_size=bs)
        return loss

    def _nonfinite_message(
        self, loss: torch.Tensor, terms: dict[str, torch.Tensor], bad: list[int]
    ) -> str:
        """One line: the loss (with this rank's terms when it is the bad one), where, what to do."""
        if torch.isfinite(loss):
            what = "non-finite"
        else:
            what = f"{loss.item()} ({', '.join(f'{k}={v.item():.4g}' for k, v in terms.items())})"
        where = (
            f" on rank {', '.join(map(str, bad))} of {dist.get_world_size()}"
            if (_distributed())
            else ""
        )
        return (
            f"loss became {what}{where} at epoch {self.current_epoch} step {self.global_step}; "
            "the last good checkpoint is kept: lower lr0, raise warmup_epochs, or run "
            "'slimseg data check'"
        )

    def on_train_batch_end(self, outputs: Any, batch: dict, batch_idx: int) -> None:
        if self.ema is not None:
            self.ema.update(self.model)

    # ---------------------------------------------------------------- validation
    @property
    def eval_model(self) -> nn.Module:
        """The weights validated, checkpointed and exported: EMA when enabled."""
        return self.ema.module if self.ema is not None else self.model

    def on_validation_epoch_start(self) -> None:
        self._val_results = []
        if self.ema is not None and dist.is_available() and dist.is_initialized():
            # each rank updated its EMA BatchNorm statistics from its own batches: validate and
            # checkpoint rank 0's on every rank (parameters are already identical under DDP)
            for buffer in self.ema.module.buffers():
                dist.broadcast(buffer, src=0)
        if self.evaluator is None and not self.semantic:
            base = self.trainer.datamodule.val_set.base
            self.evaluator = CocoEvaluator.from_dataset(base, iou_types_for(self.model))

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        # Lightning runs this step under the training autocast (16-mixed, bf16-mixed): score in
        # float32, as `slimseg val` does, so the in-training mAP (and best.pt) is that number
        with full_precision(self.device):
            self._validate_batch(batch)

    def _validate_batch(self, batch: dict) -> None:
        model = self.eval_model
        model.eval()
        if self.semantic:
            # one confusion matrix per image, keyed by id (DistributedSampler may repeat some)
            maps = semantic_batch(model, batch)
            n = self.model.num_classes + 1
            per_image = []
            for pred, target in zip(maps, batch["semantic"].cpu(), strict=True):
                cm = ConfusionMatrix(n)
                cm.update(pred, target)
                per_image.append(cm.matrix)
            self._val_results.append((list(batch["image_ids"]), per_image))
            return
        frames = detect_batch(model, batch, self.cfg.conf, self.cfg.iou, self.cfg.max_det)
        self._val_results.append((list(batch["image_ids"]), frames))

    def on_validation_epoch_end(self) -> None:
        results = self._val_results
        if _distributed():  # rank 0 scores the whole val set; the others send theirs to it
            rank0 = dist.get_rank() == 0
            gathered: list[Any] | None = [None] * dist.get_world_size() if rank0 else None
            dist.gather_object(results, gathered, dst=0)
            if not rank0:
                self.validated_epoch = self.current_epoch
                return
            results = [r for part in gathered for r in part]
        if self.semantic:
            self._semantic_epoch_end(results)
            return
        assert self.evaluator is not None
        self.evaluator.reset()
        seen: set[int] = set()
        for ids, frames in results:  # DistributedSampler may repeat images to even out ranks
            keep = [i for i, img in enumerate(ids) if img not in seen]
            seen.update(ids)
            self.evaluator.update([ids[i] for i in keep], [frames[i] for i in keep])
        metrics = self.evaluator.summarize()
        self.last_metrics = metrics
        self.validated_epoch = self.current_epoch
        box, mask = metrics["box"], metrics.get("mask")
        self.log("val/box_map50_95", box["map50_95"], prog_bar=True, sync_dist=False)
        self.log("val/box_map50", box["map50"], sync_dist=False)
        if mask:
            self.log("val/mask_map50_95", mask["map50_95"], prog_bar=True, sync_dist=False)
            self.log("val/mask_map50", mask["map50"], sync_dist=False)
        self._log_prediction_images()

    def _semantic_epoch_end(self, results: list[tuple[list[int], list[Any]]]) -> None:
        total = ConfusionMatrix(self.model.num_classes + 1)
        seen: set[int] = set()
        for ids, matrices in results:
            for img, m in zip(ids, matrices, strict=True):
                if img not in seen:
                    seen.add(img)
                    total.matrix += m
        metrics = total.compute(self.names)
        self.last_metrics = metrics
        self.validated_epoch = self.current_epoch
        self.log("val/miou", metrics["miou"], prog_bar=True, sync_dist=False)
        self.log("val/mpa", metrics["mpa"], prog_bar=True, sync_dist=False)
        self._log_prediction_images()

    def _log_prediction_images(self) -> None:
        """Predicted masks on the first 4 validation frames, as a TensorBoard image."""
        if not self.trainer.is_global_zero or not isinstance(self.logger, TensorBoardLogger):
            return
        val_set = self.trainer.datamodule.val_set
        grid = prediction_grid(self.eval_model, val_set, self.names, count=4, columns=4)
        self.logger.experiment.add_image(
            "val/predictions", grid, self.current_epoch, dataformats="HWC"
        )

    # --------------------------------------------------------------- checkpoints
    def on_save_checkpoint(self, checkpoint: dict) -> None:
        if self.ema is not None:
            checkpoint["ema"] = self.ema.state_dict()
        checkpoint["metrics"] = self.last_metrics

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        if self.ema is not None and "ema" in checkpoint:
            self.ema.load_state_dict(checkpoint["ema"])
        self.last_metrics = checkpoint.get("metrics", {})
