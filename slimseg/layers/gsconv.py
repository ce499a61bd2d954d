"""Slim-neck blocks (arXiv 2206.02424): GSConv, GSBottleneck and VoVGSCSP."""

from __future__ import annotations

import torch
from torch import nn

from slimseg.layers.conv import ConvBNAct


def channel_interleave(x: torch.Tensor) -> torch.Tensor:
    """Interleave the two channel halves: ``[a0..an-1, b0..bn-1] → [a0, b0, a1, b1, ...]``.

    ``[B, 2n, H, W] → [B, 2n, H, W]``; the batch axis is never moved (TensorRT-safe).
    """
    b, c, h, w = x.shape
    return x.reshape(b, 2, c // 2, h, w).transpose(1, 2).reshape(b, c, h, w)


class GSConv(nn.Module):
    """Dense conv to c_out/2 → depthwise 5×5 on that half → concat → channel interleave.

    Shapes: ``[B, c_in, H, W] → [B, c_out, H/s, W/s]``; ``c_out`` must be even.
    """

    def __init__(
        self,
        c_in: int,
        c_out: int,
        k: int = 1,
        s: int = 1,
        act: str | None = "silu",
        fused: bool = False,
    ) -> None:
        super().__init__()
        if c_out % 2:
            raise ValueError(f"GSConv needs an even number of output channels, got {c_out}")
        half = c_out // 2
        self.dense = ConvBNAct(c_in, half, k, s, act=act, fused=fused)
        self.depthwise = ConvBNAct(half, half, 5, 1, groups=half, act=act, fused=fused)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.dense(x)
        return channel_interleave(torch.cat((y, self.depthwise(y)), dim=1))


class GSBottleneck(nn.Module):
    """GSConv 1×1 → GSConv 3×3 (linear), plus a linear 1×1 conv shortcut; summed.

    Shapes: ``[B, c_in, H, W] → [B, c_out, H, W]``.
    """

    def __init__(self, c_in: int, c_out: int, e: float = 0.5, fused: bool = False) -> None:
        super().__init__()
        hidden = int(c_out * e)
        self.lighting = nn.Sequential(
            GSConv(c_in, hidden, 1, 1, fused=fused),
            GSConv(hidden, c_out, 3, 1, act=None, fused=fused),
        )
        self.shortcut = ConvBNAct(c_in, c_out, 1, 1, act=None, fused=fused)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.lighting(x) + self.shortcut(x)


class VoVGSCSP(nn.Module):
    """One-shot aggregation CSP block built from GSBottlenecks (the slim-neck's C2f replacement).

    Two 1×1 convs split ``c_in`` into halves of ``c_out·e``; one passes ``n`` GSBottlenecks;
    both are concatenated and mixed by a 1×1 conv. The original code's unused 3×3 ``res``
    conv is not built (see ``dead_conv_params``). Shapes: ``[B, c_in, H, W] → [B, c_out, H, W]``.
    """

    def __init__(
        self, c_in: int, c_out: int, n: int = 1, e: float = 0.5, fused: bool = False
    ) -> None:
        super().__init__()
        hidden = int(c_out * e)
        self.hidden = hidden
        self.cv1 = ConvBNAct(c_in, hidden, 1, fused=fused)
        self.cv2 = ConvBNAct(c_in, hidden, 1, fused=fused)
        self.gsb = nn.Sequential(
            *(GSBottleneck(hidden, hidden, e=1.0, fused=fused) for _ in range(n))
        )
        self.cv3 = ConvBNAct(2 * hidden, c_out, 1, fused=fused)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.cv3(torch.cat((self.cv2(x), self.gsb(self.cv1(x))), dim=1))

    @property
    def dead_conv_params(self) -> int:
        """Parameters of the original's unused 3×3 Conv+BN (``hidden → hidden``), not built here."""
        return self.hidden * self.hidden * 9 + 2 * self.hidden
