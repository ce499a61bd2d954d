"""One loss interface for every model family: ``criterion(outputs, batch) → (loss, terms)``."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

from slimseg.losses.semantic import SemanticLoss
from slimseg.losses.yolov3 import YOLOv3Loss
from slimseg.losses.yolov8_seg import YOLOv8Loss

Criterion = Callable[[object, dict], tuple[torch.Tensor, dict[str, torch.Tensor]]]


def build_criterion(model: nn.Module) -> Criterion:
    """The loss that matches ``model.spec.family``; the batch is a collate dict."""
    family = model.spec.family
    if family == "yolov8":
        loss = YOLOv8Loss(
            model.num_classes, model.strides, model.reg_max, mask_loss=model.spec.head.mask_loss
        )

        def v8(outputs: object, batch: dict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
            return loss.to(batch["images"].device)(outputs, batch["targets"], batch.get("masks"))

        return v8
    if family == "darknet-yolov3":
        v3_loss = YOLOv3Loss(model)

        def v3(outputs: object, batch: dict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
            return v3_loss(outputs, batch["targets"], tuple(batch["images"].shape[2:]))

        return v3
    if family == "msnet":
        sem_loss = SemanticLoss()

        def semantic(outputs: object, batch: dict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
            return sem_loss(outputs, batch["semantic"])

        return semantic
    raise ValueError(f"no loss for model family {family!r}")
