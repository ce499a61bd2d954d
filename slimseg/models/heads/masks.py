"""YOLOv8-seg mask branch: per-level mask coefficients and the prototype generator."""

from __future__ import annotations

import torch
from torch import nn

from slimseg.layers.conv import ConvBNAct
from slimseg.models.heads.branch import conv_branch


class Proto(nn.Module):
    """3×3 conv, 2×2 stride-2 transposed conv, 3×3 conv, 1×1 conv to ``num_masks``.

    ``[B, c_in, H, W]`` (P3) → ``[B, num_masks, 2H, 2W]`` (a quarter of the input size).
    """

    def __init__(self, c_in: int, hidden: int, num_masks: int = 32, fused: bool = False) -> None:
        super().__init__()
        self.cv1 = ConvBNAct(c_in, hidden, 3, fused=fused)
        self.upsample = nn.ConvTranspose2d(hidden, hidden, 2, 2, 0, bias=True)
        self.cv2 = ConvBNAct(hidden, hidden, 3, fused=fused)
        self.cv3 = ConvBNAct(hidden, num_masks, 1, fused=fused)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.cv3(self.cv2(self.upsample(self.cv1(x))))


class MaskCoefficients(nn.Module):
    """Per level 3×3, 3×3, 1×1 → ``num_masks`` raw coefficients, width ``max(c_P3/4, nm)``.

    Per-level inputs ``[B, c_i, H_i, W_i]`` → ``[B, num_masks, A]`` with ``A = Σ H_i·W_i``.
    """

    def __init__(self, in_channels: tuple[int, ...], num_masks: int, fused: bool = False) -> None:
        super().__init__()
        width = max(in_channels[0] // 4, num_masks)
        self.branches = nn.ModuleList(conv_branch(c, width, num_masks, fused) for c in in_channels)
        self.num_masks = num_masks

    def forward(self, feats: list[torch.Tensor]) -> torch.Tensor:
        b = feats[0].shape[0]
        return torch.cat(
            [
                m(x).reshape(b, self.num_masks, -1)
                for x, m in zip(feats, self.branches, strict=True)
            ],
            dim=2,
        )
