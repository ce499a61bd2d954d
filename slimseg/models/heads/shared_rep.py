"""Parameter-sharing decoupled head with RepConv (the substation paper's "-rep" head)."""

from __future__ import annotations

import torch
from torch import nn

from slimseg.layers.conv import ConvBNAct
from slimseg.layers.rep import RepConv
from slimseg.models.heads.decoupled import class_bias_prior


class SharedRepDetect(nn.Module):
    """Per level a 3×3 stem to ``hidden``; one RepConv shared by all levels (or one per level
    when ``share_repconv=False``); shared 1×1 box (4·reg_max) and class (nc) predictors; a
    learnable scalar per level multiplies that level's box logits.

    Input ``[B, c_i, H_i, W_i]`` per level; output per level ``[B, 4·reg_max + nc, H_i, W_i]``.
    """

    def __init__(
        self,
        in_channels: tuple[int, ...],
        num_classes: int,
        hidden: int,
        share_repconv: bool = True,
        reg_max: int = 16,
        fused: bool = False,
    ) -> None:
        super().__init__()
        levels = len(in_channels)
        self.stems = nn.ModuleList(ConvBNAct(c, hidden, 3, fused=fused) for c in in_channels)
        n_rep = 1 if share_repconv else levels
        self.rep = nn.ModuleList(RepConv(hidden, hidden, fused=fused) for _ in range(n_rep))
        self.box = nn.Conv2d(hidden, 4 * reg_max, 1)
        self.cls = nn.Conv2d(hidden, num_classes, 1)
        self.box_scale = nn.Parameter(torch.ones(levels))
        self.num_classes = num_classes

    def forward(self, feats: list[torch.Tensor]) -> list[torch.Tensor]:
        out = []
        for i, (x, stem) in enumerate(zip(feats, self.stems, strict=True)):
            rep = self.rep[i if len(self.rep) > 1 else 0]
            y = rep(stem(x))
            out.append(torch.cat((self.box(y) * self.box_scale[i], self.cls(y)), dim=1))
        return out

    @torch.no_grad()
    def init_biases(self, strides: tuple[int, ...]) -> None:
        """Box bias 1.0; one class bias for all levels, from the middle stride's prior."""
        self.box.bias.fill_(1.0)
        self.cls.bias.fill_(class_bias_prior(self.num_classes, strides[len(strides) // 2]))
