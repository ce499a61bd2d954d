"""The YOLOv8 per-level head branch: two 3×3 Conv+BN+SiLU, then a 1×1 predictor with bias."""

from __future__ import annotations

from torch import nn

from slimseg.layers.conv import ConvBNAct


def conv_branch(c_in: int, width: int, c_out: int, fused: bool = False) -> nn.Sequential:
    """``[B, c_in, H, W] → [B, c_out, H, W]`` through 3×3 (width), 3×3 (width), 1×1 (c_out)."""
    return nn.Sequential(
        ConvBNAct(c_in, width, 3, fused=fused),
        ConvBNAct(width, width, 3, fused=fused),
        nn.Conv2d(width, c_out, 1),
    )
