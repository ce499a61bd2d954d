"""Freezing top-level parts of a network during training (fine-tuning a head on a trunk).

``FreezeModules(["backbone", "neck", "detect"])`` keeps those children of the trained
network fixed: their parameters get no gradient (so the optimizer, which skips parameters
without one, never moves them, weight decay included) and their BatchNorm layers stay in
eval mode (running statistics unchanged). What stays trainable is everything else, e.g. the
mask branch (``mask_coeffs``, ``proto``) of a YOLOv8-seg model.
"""

from __future__ import annotations

from collections.abc import Sequence

import lightning as L
from torch import nn

from slimseg.errors import SlimsegError


def frozen_children(model: nn.Module, names: Sequence[str]) -> list[nn.Module]:
    """The named top-level children of ``model``; an unknown name is a one-line error."""
    children = dict(model.named_children())
    unknown = [n for n in names if n not in children]
    if unknown:
        raise SlimsegError(
            f"--freeze {','.join(unknown)}: {type(model).__name__} has no such part; "
            f"valid: {', '.join(children)}"
        )
    if len(set(names)) == len(children):
        raise SlimsegError(f"--freeze {','.join(names)} leaves nothing to train")
    return [children[n] for n in names]


class FreezeModules(L.Callback):
    """Lightning callback: freeze ``names`` (top-level children of ``pl_module.model``)."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = tuple(names)

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        # before the strategy wraps the module (DDP registers the parameters that need
        # gradients when it wraps; on_fit_start is too late: the frozen ones would be waited
        # for, "parameters that were not used in producing the loss") and before the
        # optimizer is built (it then holds only the trained parameters)
        for part in frozen_children(pl_module.model, self.names):
            part.requires_grad_(False)

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        for part in frozen_children(pl_module.model, self.names):
            part.eval()  # BatchNorm statistics stay those of the trained trunk
