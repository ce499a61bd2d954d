"""MSNET's head: multiclass feature enhancement, upsampling, multiclass feature guidance.

Shapes below for an ``H × W`` input, ``K`` classes, head width ``D``.

* :class:`MultiClassEnhancement`: ``K`` learned 3×3 filters over C5, one per class, give
  ``K`` class-response maps; they are concatenated with a 1×1 projection of C5 and fused
  (1×1 Conv-BN-SiLU, residual) into the enhanced map ``E [B, D, H/32, W/32]``. A Transformer
  decoder then lets ``K + 1`` learned class queries (query 0 = background) attend to the
  tokens of ``E``; two MLPs turn each query into a class embedding and a mask embedding
  ``[B, K + 1, D]``.
* :class:`PixelDecoder` (upsampling): 1×1 laterals of C2, C3, C4 and ``E`` to ``D``
  channels, bilinearly upsampled to stride 4, concatenated, 1×1 Conv-BN-SiLU → ``[B, D, H/4,
  W/4]`` (the SegFormer-style all-1×1 decoder, cheaper than an FPN of 3×3 convs).
* :class:`MultiClassGuidance`: channel attention (shared 2-layer 1×1 MLP on the average- and
  max-pooled map, summed, sigmoid) and spatial attention (channel-wise mean and max, 3×3
  conv, sigmoid) gate the pixel features separately; the two gated maps are concatenated
  and mixed by a 1×1 Conv-BN-SiLU into ``F [B, D, H/4, W/4]``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from slimseg.layers.conv import ConvBNAct
from slimseg.models.msnet.attention import MLP, DecoderLayer
from slimseg.models.msnet.backbone import resize_pos_embed


class MultiClassEnhancement(nn.Module):
    """C5 ``[B, c5, h, w]`` → ``(E [B, D, h, w], class_emb [B, K+1, D], mask_emb [B, K+1, D])``."""

    def __init__(
        self,
        c5: int,
        hidden: int,
        num_classes: int,
        layers: int,
        heads: int,
        pos_hw: tuple[int, int],
        mlp_ratio: float,
        dropout: float = 0.0,
        fused: bool = False,
    ) -> None:
        super().__init__()
        self.proj = ConvBNAct(c5, hidden, 1, fused=fused)
        self.class_filters = nn.Conv2d(c5, num_classes, 3, 1, 1)  # one filter per class
        self.fuse = ConvBNAct(hidden + num_classes, hidden, 1, fused=fused)
        self.memory_pos = nn.Parameter(torch.zeros(1, hidden, *pos_hw))
        nn.init.trunc_normal_(self.memory_pos, std=0.02)
        queries = num_classes + 1
        self.query_feat = nn.Parameter(torch.zeros(1, queries, hidden))
        self.query_pos = nn.Parameter(torch.zeros(1, queries, hidden))
        nn.init.trunc_normal_(self.query_feat, std=0.02)
        nn.init.trunc_normal_(self.query_pos, std=0.02)
        self.layers = nn.ModuleList(
            DecoderLayer(hidden, heads, mlp_ratio, dropout) for _ in range(layers)
        )
        self.norm = nn.LayerNorm(hidden)
        self.class_head = MLP(hidden, hidden, hidden)
        self.mask_head = MLP(hidden, hidden, hidden)

    def forward(self, c5: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        p = self.proj(c5)
        e = p + self.fuse(torch.cat([p, self.class_filters(c5)], dim=1))
        b, _, h, w = e.shape
        memory = e.flatten(2).transpose(1, 2)  # [B, hw, D]
        # copies, not views of the parameters: FlopCounterMode's module tracker rejects views
        # of leaf tensors made under no_grad as module inputs
        memory_pos = resize_pos_embed(self.memory_pos, (h, w)).repeat(b, 1, 1)
        q = self.query_feat.repeat(b, 1, 1)
        q_pos = self.query_pos.repeat(b, 1, 1)
        for layer in self.layers:
            q = layer(q, q_pos, memory, memory_pos)
        q = self.norm(q)
        return e, self.class_head(q), self.mask_head(q)


class PixelDecoder(nn.Module):
    """``[C2, C3, C4, E]`` → ``[B, D, H/4, W/4]`` (1×1 laterals, upsample, concat, 1×1)."""

    def __init__(self, channels: tuple[int, ...], hidden: int, fused: bool = False) -> None:
        super().__init__()
        self.laterals = nn.ModuleList(ConvBNAct(c, hidden, 1, fused=fused) for c in channels)
        self.mix = ConvBNAct(hidden * len(channels), hidden, 1, fused=fused)

    def forward(self, feats: list[torch.Tensor]) -> torch.Tensor:
        size = feats[0].shape[2:]
        maps = []
        for lateral, f in zip(self.laterals, feats, strict=True):
            x = lateral(f)
            if x.shape[2:] != size:
                x = F.interpolate(x, size=size, mode="bilinear", align_corners=False)
            maps.append(x)
        return self.mix(torch.cat(maps, dim=1))


class MultiClassGuidance(nn.Module):
    """Channel and spatial attention, concatenated: ``[B, D, h, w] → [B, D, h, w]``."""

    def __init__(self, hidden: int, reduction: int = 4, fused: bool = False) -> None:
        super().__init__()
        mid = max(hidden // reduction, 8)
        self.channel_mlp = nn.Sequential(
            nn.Conv2d(hidden, mid, 1), nn.SiLU(), nn.Conv2d(mid, hidden, 1)
        )
        self.spatial = nn.Conv2d(2, 1, 3, 1, 1)
        self.mix = ConvBNAct(2 * hidden, hidden, 1, fused=fused)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        avg = x.mean(dim=(2, 3), keepdim=True)
        mx = x.amax(dim=(2, 3), keepdim=True)
        channel_gate = (self.channel_mlp(avg) + self.channel_mlp(mx)).sigmoid()  # [B, D, 1, 1]
        pooled = torch.cat([x.mean(dim=1, keepdim=True), x.amax(dim=1, keepdim=True)], dim=1)
        spatial_gate = self.spatial(pooled).sigmoid()  # [B, 1, h, w]
        return self.mix(torch.cat([x * channel_gate, x * spatial_gate], dim=1))
