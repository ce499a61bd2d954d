"""YOLOv8 PAN neck, with C2f blocks (baseline) or the GSConv slim-neck (-gs)."""

from __future__ import annotations

import torch
from torch import nn

from slimseg.layers.conv import ConvBNAct
from slimseg.layers.csp import C2f
from slimseg.layers.gsconv import GSConv, VoVGSCSP
from slimseg.models.specs import NECKS, ScaleSpec


class PAN(nn.Module):
    """Top-down then bottom-up feature pyramid over P3, P4, P5.

    ``kind="c2f"``: the reference YOLOv8 neck (four C2f without shortcut, two 3×3/2 convs).
    ``kind="slim"``: the four C2f become VoVGSCSP and the two downsampling convs GSConv(3, 2).
    Inputs ``(P3, P4, P5)`` with ``in_channels``; outputs the same strides with
    ``out_channels`` (s scale: 128, 256, 512).
    """

    def __init__(
        self,
        in_channels: tuple[int, int, int],
        scaler: ScaleSpec,
        kind: str = "c2f",
        fused: bool = False,
    ) -> None:
        super().__init__()
        if kind not in NECKS:
            raise ValueError(f"unknown neck {kind!r}; valid: {list(NECKS)}")
        self.kind = kind
        c3_in, c4_in, c5_in = in_channels
        c256, c512, c1024 = (scaler.channels(c) for c in (256, 512, 1024))
        n = scaler.repeats(3)

        def block(c_in: int, c_out: int) -> nn.Module:
            if kind == "slim":
                return VoVGSCSP(c_in, c_out, n, fused=fused)
            return C2f(c_in, c_out, n, shortcut=False, fused=fused)

        def down(c: int) -> nn.Module:
            if kind == "slim":
                return GSConv(c, c, 3, 2, fused=fused)
            return ConvBNAct(c, c, 3, 2, fused=fused)

        self.upsample = nn.Upsample(scale_factor=2.0, mode="nearest")
        self.top_down4 = block(c5_in + c4_in, c512)
        self.top_down3 = block(c512 + c3_in, c256)
        self.down3 = down(c256)
        self.bottom_up4 = block(c256 + c512, c512)
        self.down4 = down(c512)
        self.bottom_up5 = block(c512 + c5_in, c1024)
        self.out_channels = (c256, c512, c1024)

    def forward(
        self, feats: tuple[torch.Tensor, torch.Tensor, torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        p3, p4, p5 = feats
        h4 = self.top_down4(torch.cat((self.upsample(p5), p4), dim=1))
        o3 = self.top_down3(torch.cat((self.upsample(h4), p3), dim=1))
        o4 = self.bottom_up4(torch.cat((self.down3(o3), h4), dim=1))
        o5 = self.bottom_up5(torch.cat((self.down4(o4), p5), dim=1))
        return o3, o4, o5

    def dead_conv_params(self) -> int:
        """Parameters the original slim-neck code defines but never uses (0 for C2f)."""
        return sum(m.dead_conv_params for m in self.modules() if isinstance(m, VoVGSCSP))
