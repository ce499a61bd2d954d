"""MSNET, VTD-SLAM's Vision-Transformer semantic segmenter (docs/papers.md §5), as a zoo family.

``images [B, 3, H, W]`` (RGB in [0, 1], H and W multiples of 32) → per-pixel class logits
``[B, K + 1, H, W]``: channel 0 is background, channel ``k + 1`` is class ``k`` of the
dataset. The same tensor is returned in training and eval mode (and by the ONNX export, as
``logits``); the class map is its argmax over dim 1.

Pipeline (details in :mod:`~slimseg.models.msnet.backbone` and
:mod:`~slimseg.models.msnet.head`): residual dual-pyramid backbone → C2..C5; multiclass
feature enhancement on C5 (class filters, Transformer decoder over ``K + 1`` class queries →
class and mask embeddings); upsampling of the pyramid to stride 4; multiclass feature
guidance (channel + spatial attention) → pixel features ``F [B, D, H/4, W/4]``; then

    logits[b, k] = (mask_emb[b, k] ⊙ sigmoid(class_emb[b, k])) · F[b] / √D + bias[k]

i.e. the guided features are multiplied by the class head (a per-class channel gate) and
then by the mask head (a per-class linear filter), as the paper's "multiplied with the class
head, then with the mask head" describes; the result is bilinearly upsampled ×4.

Choices where the paper is vague (documented here, tunable in the spec where it matters):

* patch size ``max(1, token_stride / level stride)`` so every PEncoder attends over a coarse
  grid (stride 32 for ``msnet-t``, 16 for ``msnet-s``): full-resolution attention at stride 4
  would be quadratic in ``(H/4)(W/4)`` tokens;
* learned position embeddings at a ``pos_imgsz`` input, bilinearly resized to other sizes;
* pre-norm blocks, GELU MLPs, SiLU in every Conv-BN-act (as the YOLO zoo);
* one class query per class plus one for background (no Hungarian matching: query ``k`` is
  output channel ``k``, so plain per-pixel cross-entropy + dice trains it);
* pyramid fusion into C5 by max-pooling C2..C4 to stride 32, concatenation and a 1×1 conv;
* dropout ``spec.msnet.dropout`` in the Transformer blocks and on ``F`` (the paper's 0.56 is
  for a COCO-scale model; the tiny preset uses 0).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from slimseg.models.base import ZooModel
from slimseg.models.msnet.backbone import STRIDES, DualPyramidBackbone
from slimseg.models.msnet.head import MultiClassEnhancement, MultiClassGuidance, PixelDecoder
from slimseg.models.specs import ModelSpec


class MSNet(ZooModel):
    """MSNET built from a ``ModelSpec`` of family ``msnet`` (see the module docstring)."""

    def __init__(self, spec: ModelSpec, fused: bool = False) -> None:
        super().__init__(spec)
        if spec.msnet is None:
            raise ValueError(f"{spec.name}: not an msnet spec")
        m = spec.msnet
        self.strides = STRIDES
        self.backbone = DualPyramidBackbone(
            m.stem_channels,
            m.channels,
            m.embed_dims,
            m.depths,
            m.heads,
            m.token_stride,
            m.pos_imgsz,
            m.mlp_ratio,
            m.dropout,
            fused,
        )
        grid = m.pos_imgsz // 32
        self.enhance = MultiClassEnhancement(
            m.channels[-1],
            m.hidden,
            spec.num_classes,
            m.decoder_layers,
            m.decoder_heads,
            (grid, grid),
            m.mlp_ratio,
            m.dropout,
            fused,
        )
        self.pixel_decoder = PixelDecoder((*m.channels[:3], m.hidden), m.hidden, fused)
        self.guidance = MultiClassGuidance(m.hidden, fused=fused)
        self.drop = nn.Dropout2d(m.dropout)
        self.class_bias = nn.Parameter(torch.zeros(spec.num_classes + 1))
        self.scale = m.hidden**-0.5

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """``[B, 3, H, W]`` → logits ``[B, K + 1, H, W]`` (index 0 = background)."""
        c2, c3, c4, c5 = self.backbone(images)
        e, class_emb, mask_emb = self.enhance(c5)
        pixels = self.drop(self.guidance(self.pixel_decoder([c2, c3, c4, e])))
        b, d, h, w = pixels.shape
        filters = mask_emb * class_emb.sigmoid() * self.scale  # [B, K+1, D]
        logits = torch.matmul(filters, pixels.reshape(b, d, h * w))  # [B, K+1, h·w]
        logits = logits.reshape(b, -1, h, w) + self.class_bias.reshape(1, -1, 1, 1)
        return F.interpolate(logits, size=images.shape[2:], mode="bilinear", align_corners=False)
