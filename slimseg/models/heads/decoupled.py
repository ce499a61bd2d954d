"""The YOLOv8 decoupled detection head (separate box and class branches per level)."""

from __future__ import annotations

import math

import torch
from torch import nn

from slimseg.models.heads.branch import conv_branch


def class_bias_prior(num_classes: int, stride: int, imgsz: int = 640) -> float:
    """Class-logit bias for ~5 objects per ``imgsz`` image: ``log(5 / nc / (imgsz / s)²)``."""
    return math.log(5 / num_classes / (imgsz / stride) ** 2)


class DecoupledDetect(nn.Module):
    """Per level: box branch (3×3, 3×3, 1×1 → 4·reg_max) and class branch (3×3, 3×3, 1×1 → nc).

    Widths follow YOLOv8: box ``max(16, c_P3/4, 4·reg_max)``, class ``max(c_P3, min(nc, 100))``
    (the original v8 class branch with two dense 3×3 convs). Input ``[B, c_i, H_i, W_i]`` per
    level; output per level ``[B, 4·reg_max + nc, H_i, W_i]`` (box logits first).
    """

    def __init__(
        self,
        in_channels: tuple[int, ...],
        num_classes: int,
        reg_max: int = 16,
        fused: bool = False,
    ) -> None:
        super().__init__()
        c_box = max(16, in_channels[0] // 4, 4 * reg_max)
        c_cls = max(in_channels[0], min(num_classes, 100))
        self.box = nn.ModuleList(conv_branch(c, c_box, 4 * reg_max, fused) for c in in_channels)
        self.cls = nn.ModuleList(conv_branch(c, c_cls, num_classes, fused) for c in in_channels)
        self.num_classes = num_classes

    def forward(self, feats: list[torch.Tensor]) -> list[torch.Tensor]:
        return [
            torch.cat((box(x), cls(x)), dim=1)
            for x, box, cls in zip(feats, self.box, self.cls, strict=True)
        ]

    @torch.no_grad()
    def init_biases(self, strides: tuple[int, ...]) -> None:
        """Box logits bias 1.0; class bias from the ~5-objects-per-image prior per stride."""
        for box, cls, s in zip(self.box, self.cls, strides, strict=True):
            box[-1].bias.fill_(1.0)
            cls[-1].bias.fill_(class_bias_prior(self.num_classes, s))
