"""YOLOv8 backbone (CSPDarknet with C2f blocks and SPPF)."""

from __future__ import annotations

import torch
from torch import nn

from slimseg.layers.conv import ConvBNAct
from slimseg.layers.csp import SPPF, C2f
from slimseg.models.specs import ScaleSpec


class CSPDarknet(nn.Module):
    """Stem + four stride-2 stages; returns P3, P4, P5 (strides 8, 16, 32).

    ``[B, 3, H, W] → ([B, c3, H/8, W/8], [B, c4, H/16, W/16], [B, c5, H/32, W/32])`` with
    ``(c3, c4, c5) = self.out_channels`` (s scale: 128, 256, 512).
    """

    def __init__(self, scaler: ScaleSpec, fused: bool = False) -> None:
        super().__init__()
        c64, c128, c256, c512, c1024 = (scaler.channels(c) for c in (64, 128, 256, 512, 1024))
        r3, r6 = scaler.repeats(3), scaler.repeats(6)
        self.stem = nn.Sequential(
            ConvBNAct(3, c64, 3, 2, fused=fused),
            ConvBNAct(c64, c128, 3, 2, fused=fused),
            C2f(c128, c128, r3, shortcut=True, fused=fused),
        )
        self.stage3 = nn.Sequential(
            ConvBNAct(c128, c256, 3, 2, fused=fused),
            C2f(c256, c256, r6, shortcut=True, fused=fused),
        )
        self.stage4 = nn.Sequential(
            ConvBNAct(c256, c512, 3, 2, fused=fused),
            C2f(c512, c512, r6, shortcut=True, fused=fused),
        )
        self.stage5 = nn.Sequential(
            ConvBNAct(c512, c1024, 3, 2, fused=fused),
            C2f(c1024, c1024, r3, shortcut=True, fused=fused),
            SPPF(c1024, c1024, 5, fused=fused),
        )
        self.out_channels = (c256, c512, c1024)
        self.skip_channels = {2: c64, 4: c128}  # stride → channels of ``features``' extras

    def features(self, x: torch.Tensor) -> tuple[dict[int, torch.Tensor], tuple[torch.Tensor, ...]]:
        """``({2: [B, c64, H/2, W/2], 4: [B, c128, H/4, W/4]}, (P3, P4, P5))``: the stem
        conv and stride-4 C2f outputs (for a prototype path that takes them) and the
        pyramid of ``forward``."""
        s2 = self.stem[0](x)
        s4 = self.stem[2](self.stem[1](s2))
        p3 = self.stage3(s4)
        p4 = self.stage4(p3)
        return {2: s2, 4: s4}, (p3, p4, self.stage5(p4))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        p3 = self.stage3(self.stem(x))
        p4 = self.stage4(p3)
        return p3, p4, self.stage5(p4)
