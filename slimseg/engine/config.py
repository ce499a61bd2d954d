"""Training recipe: a frozen dataclass loaded from a YAML (shipped: ``slimseg/configs/train``)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from slimseg.errors import SlimsegError
from slimseg.ops.nms import EVAL_CONF, MAX_DET, NMS_IOU
from slimseg.utils.shipped import resolve_config
from slimseg.utils.strict_dataclass import dataclass_from_mapping
from slimseg.utils.yaml_io import read_yaml

OPTIMIZERS = ("sgd", "adamw")


@dataclass(frozen=True)
class TrainConfig:
    """Everything about how a model is trained (YOLOv8 recipe defaults, docs/architecture.md §6)."""

    epochs: int = 100
    batch: int = 16
    imgsz: int = 640
    optimizer: str = "sgd"  # sgd (momentum, nesterov) | adamw
    lr0: float = 0.01
    lrf: float = 0.01  # final lr = lr0 · lrf
    cos_lr: bool = False  # cosine instead of linear decay
    momentum: float = 0.937  # SGD momentum / Adam beta1
    weight_decay: float = 5e-4  # conv/linear weights only
    warmup_epochs: float = 3.0
    warmup_momentum: float = 0.8
    warmup_bias_lr: float = 0.1
    close_mosaic: int = 10  # last epochs without mosaic
    ema: bool = True
    ema_decay: float = 0.9999
    grad_clip: float = 10.0  # max gradient norm (0 = off)
    amp: bool = True  # mixed precision on GPU (ignored on CPU)
    seed: int = 0
    workers: int = 2
    threads: int = 0  # torch intra-op threads on CPU (0 = all cores)
    sync_bn: bool = False  # SyncBatchNorm under DDP
    conf: float = EVAL_CONF  # validation score threshold
    iou: float = NMS_IOU  # validation NMS IoU
    max_det: int = MAX_DET
    val_every: int = 1  # validate every N epochs (make epochs a multiple to score the last)

    def __post_init__(self) -> None:
        if self.optimizer not in OPTIMIZERS:
            raise SlimsegError(f"optimizer={self.optimizer!r} is not one of {list(OPTIMIZERS)}")
        if self.imgsz % 32:
            raise SlimsegError(f"imgsz={self.imgsz} is not a multiple of 32")
        if self.epochs < 1 or self.batch < 1:
            raise SlimsegError(f"epochs and batch must be >= 1 (got {self.epochs}, {self.batch})")

    def override(self, **values: Any) -> TrainConfig:
        """Copy with the non-None values replaced (CLI flags)."""
        return replace(self, **{k: v for k, v in values.items() if v is not None})


def load_train_config(path: str | Path | None) -> TrainConfig:
    """Read a recipe YAML (None → defaults); unknown fields are named with the valid ones."""
    if path is None:
        return TrainConfig()
    path = resolve_config(path, "train", "train config")
    data = read_yaml(path, "train config") or {}
    return dataclass_from_mapping(TrainConfig, data, str(path))
