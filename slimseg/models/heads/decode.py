"""Anchor-free decoding shared by the YOLOv8 heads: anchor points and the DFL expectation."""

from __future__ import annotations

import torch
from torch import nn

# Output strides of every YOLO head in the zoo (P3, P4, P5), finest first.
YOLO_STRIDES: tuple[int, int, int] = (8, 16, 32)


def anchor_points(
    sizes: list[tuple[int, int]], strides: tuple[int, ...], like: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Cell-centre anchors for feature maps of ``sizes`` ``[(H_i, W_i)]``.

    Returns ``points [A, 2]`` (x, y in grid units of their level, i.e. ``col + 0.5``) and
    ``stride [A, 1]``, levels concatenated in order, cells row-major.
    """
    points, stride_col = [], []
    for (h, w), s in zip(sizes, strides, strict=True):
        ys = torch.arange(h, device=like.device, dtype=like.dtype) + 0.5
        xs = torch.arange(w, device=like.device, dtype=like.dtype) + 0.5
        gy, gx = torch.meshgrid(ys, xs, indexing="ij")
        points.append(torch.stack((gx, gy), -1).reshape(-1, 2))
        stride_col.append(torch.full((h * w, 1), float(s), device=like.device, dtype=like.dtype))
    return torch.cat(points), torch.cat(stride_col)


class DistributionFocalDecode(nn.Module):
    """Expected value of a discrete distribution over ``reg_max`` bins per box side.

    ``[B, 4·reg_max, A]`` logits → ``[B, 4, A]`` distances (in stride units). The bin values
    ``0..reg_max-1`` live in a frozen 1×1 conv, counted as parameters but not gradients, as in
    the reference model.
    """

    def __init__(self, reg_max: int = 16) -> None:
        super().__init__()
        self.reg_max = reg_max
        self.proj = nn.Conv2d(reg_max, 1, 1, bias=False).requires_grad_(False)
        with torch.no_grad():
            self.proj.weight.copy_(torch.arange(reg_max, dtype=torch.float32).view(1, -1, 1, 1))

    def forward(self, logits: torch.Tensor) -> torch.Tensor:
        b, _, a = logits.shape
        probs = logits.view(b, 4, self.reg_max, a).transpose(1, 2).softmax(1)
        return self.proj(probs).view(b, 4, a)


def distances_to_xywh(dist: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``dist [B, 4, A]`` (left, top, right, bottom) from ``points [A, 2]`` → xywh ``[B, 4, A]``."""
    lt, rb = dist.split((2, 2), dim=1)
    pts = points.transpose(0, 1).unsqueeze(0)
    x1y1, x2y2 = pts - lt, pts + rb
    return torch.cat(((x1y1 + x2y2) / 2, x2y2 - x1y1), dim=1)
