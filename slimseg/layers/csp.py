"""YOLOv8 CSP blocks: Bottleneck, C2f and SPPF."""

from __future__ import annotations

import torch
from torch import nn

from slimseg.layers.conv import ConvBNAct


class Bottleneck(nn.Module):
    """3×3 conv → 3×3 conv with an optional residual. ``[B, c_in, H, W] → [B, c_out, H, W]``."""

    def __init__(
        self, c_in: int, c_out: int, shortcut: bool = True, e: float = 1.0, fused: bool = False
    ) -> None:
        super().__init__()
        hidden = int(c_out * e)
        self.cv1 = ConvBNAct(c_in, hidden, 3, fused=fused)
        self.cv2 = ConvBNAct(hidden, c_out, 3, fused=fused)
        self.add = shortcut and c_in == c_out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.cv2(self.cv1(x))
        return x + y if self.add else y


class C2f(nn.Module):
    """CSP block with two convs and ``n`` chained bottlenecks whose outputs are all kept.

    1×1 conv to ``2c`` (``c = c_out·e``), split in halves, chain ``n`` bottlenecks on the
    second half, concatenate all ``n + 2`` maps, 1×1 conv to ``c_out``.
    Shapes: ``[B, c_in, H, W] → [B, c_out, H, W]``.
    """

    def __init__(
        self,
        c_in: int,
        c_out: int,
        n: int = 1,
        shortcut: bool = False,
        e: float = 0.5,
        fused: bool = False,
    ) -> None:
        super().__init__()
        self.hidden = int(c_out * e)
        self.cv1 = ConvBNAct(c_in, 2 * self.hidden, 1, fused=fused)
        self.cv2 = ConvBNAct((2 + n) * self.hidden, c_out, 1, fused=fused)
        self.blocks = nn.ModuleList(
            Bottleneck(self.hidden, self.hidden, shortcut, e=1.0, fused=fused) for _ in range(n)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        parts = list(self.cv1(x).split((self.hidden, self.hidden), dim=1))
        for block in self.blocks:
            parts.append(block(parts[-1]))
        return self.cv2(torch.cat(parts, dim=1))


class SPPF(nn.Module):
    """Spatial pyramid pooling (fast): 1×1 conv, three chained k×k max-pools, concat, 1×1 conv.

    Shapes: ``[B, c_in, H, W] → [B, c_out, H, W]``.
    """

    def __init__(self, c_in: int, c_out: int, k: int = 5, fused: bool = False) -> None:
        super().__init__()
        hidden = c_in // 2
        self.cv1 = ConvBNAct(c_in, hidden, 1, fused=fused)
        self.cv2 = ConvBNAct(4 * hidden, c_out, 1, fused=fused)
        self.pool = nn.MaxPool2d(k, 1, k // 2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = [self.cv1(x)]
        for _ in range(3):
            y.append(self.pool(y[-1]))
        return self.cv2(torch.cat(y, dim=1))
