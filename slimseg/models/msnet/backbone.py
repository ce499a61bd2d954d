"""MSNET's residual dual-pyramid backbone: a convolutional pyramid with a ViT per level.

Per level ``i`` (C2..C5, strides 4, 8, 16, 32): ``P_i = down(C_{i-1})`` (3×3 stride-2
Conv-BN-SiLU), ``T_i = PEncoder(P_i)`` (patch + position embedding, ``L_i`` pre-norm
Transformer blocks, tokens back to a map, upsampled to ``P_i``'s size), and
``C_i = P_i + fuse([P_i, T_i])`` (concatenation, 1×1 Conv-BN-SiLU, residual to ``P_i``). The
pyramid is then fused into C5: C2..C4 are max-pooled to stride 32, concatenated with C5 and
mixed by a 1×1 Conv-BN-SiLU (again residual to C5).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from slimseg.layers.conv import ConvBNAct
from slimseg.models.msnet.attention import EncoderBlock

STRIDES = (4, 8, 16, 32)


def resize_pos_embed(pos: torch.Tensor, grid: tuple[int, int]) -> torch.Tensor:
    """Learned position embedding ``[1, C, h0, w0]`` → ``[1, h·w, C]`` for a ``grid = (h, w)``
    token grid (bilinear, half-pixel centres; unchanged at the size it was learned for)."""
    if tuple(pos.shape[2:]) != tuple(grid):
        pos = F.interpolate(pos, size=grid, mode="bilinear", align_corners=False)
    return pos.flatten(2).transpose(1, 2)


class PEncoder(nn.Module):
    """Patch + position embedding and ``depth`` ViT blocks: ``[B, c_in, H, W] → [B, dim, H,
    W]``.

    Patches are ``patch × patch`` pixels (a strided conv), so the token grid is ``H/patch ×
    W/patch``; the encoded tokens are reshaped to a map and upsampled (bilinear) to ``H × W``.
    The position embedding is learned on the grid of a ``pos_hw`` input map.
    """

    def __init__(
        self,
        c_in: int,
        dim: int,
        depth: int,
        heads: int,
        patch: int,
        pos_hw: tuple[int, int],
        mlp_ratio: float,
        dropout: float = 0.0,
    ) -> None:
        super().__init__()
        self.patch = patch
        self.embed = nn.Conv2d(c_in, dim, patch, patch)
        grid = (max(pos_hw[0] // patch, 1), max(pos_hw[1] // patch, 1))
        self.pos = nn.Parameter(torch.zeros(1, dim, *grid))
        nn.init.trunc_normal_(self.pos, std=0.02)
        self.blocks = nn.Sequential(
            *(EncoderBlock(dim, heads, mlp_ratio, dropout) for _ in range(depth))
        )
        self.norm = nn.LayerNorm(dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[2:]
        t = self.embed(x)  # [B, dim, h/p, w/p]
        b, c, gh, gw = t.shape
        tokens = t.flatten(2).transpose(1, 2) + resize_pos_embed(self.pos, (gh, gw))
        tokens = self.norm(self.blocks(tokens))
        t = tokens.transpose(1, 2).reshape(b, c, gh, gw)
        if (gh, gw) != (h, w):
            t = F.interpolate(t, size=(h, w), mode="bilinear", align_corners=False)
        return t


class DualPyramidLevel(nn.Module):
    """One level: downsample, PEncoder, concatenate, 1×1 fuse, residual.

    ``[B, c_in, H, W] → [B, c_out, H/2, W/2]``.
    """

    def __init__(
        self,
        c_in: int,
        c_out: int,
        dim: int,
        depth: int,
        heads: int,
        patch: int,
        pos_hw: tuple[int, int],
        mlp_ratio: float,
        dropout: float,
        fused: bool = False,
    ) -> None:
        super().__init__()
        self.down = ConvBNAct(c_in, c_out, 3, 2, fused=fused)
        self.encoder = PEncoder(c_out, dim, depth, heads, patch, pos_hw, mlp_ratio, dropout)
        self.fuse = ConvBNAct(c_out + dim, c_out, 1, fused=fused)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        p = self.down(x)
        return p + self.fuse(torch.cat([p, self.encoder(p)], dim=1))


class DualPyramidBackbone(nn.Module):
    """``images [B, 3, H, W]`` (H, W multiples of 32) → ``[C2, C3, C4, C5]`` at strides 4, 8,
    16, 32 with ``channels`` channels; C5 already fuses the whole pyramid."""

    def __init__(
        self,
        stem_channels: int,
        channels: tuple[int, ...],
        embed_dims: tuple[int, ...],
        depths: tuple[int, ...],
        heads: tuple[int, ...],
        token_stride: int,
        pos_imgsz: int,
        mlp_ratio: float,
        dropout: float = 0.0,
        fused: bool = False,
    ) -> None:
        super().__init__()
        self.out_channels = tuple(channels)
        self.stem = ConvBNAct(3, stem_channels, 3, 2, fused=fused)  # C1, stride 2
        levels = []
        c_prev = stem_channels
        for i, stride in enumerate(STRIDES):
            size = pos_imgsz // stride
            levels.append(
                DualPyramidLevel(
                    c_prev,
                    channels[i],
                    embed_dims[i],
                    depths[i],
                    heads[i],
                    max(1, token_stride // stride),
                    (size, size),
                    mlp_ratio,
                    dropout,
                    fused,
                )
            )
            c_prev = channels[i]
        self.levels = nn.ModuleList(levels)
        self.pyramid_fuse = ConvBNAct(sum(channels), channels[-1], 1, fused=fused)

    def forward(self, images: torch.Tensor) -> list[torch.Tensor]:
        x = self.stem(images)
        feats = []
        for level in self.levels:
            x = level(x)
            feats.append(x)
        c5 = feats[-1]
        pooled = [F.max_pool2d(f, 2 ** (3 - i)) for i, f in enumerate(feats[:-1])]
        feats[-1] = c5 + self.pyramid_fuse(torch.cat([*pooled, c5], dim=1))
        return feats
