"""RepConv: a multi-branch 3×3 block for training that fuses into one 3×3 conv for inference."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from slimseg.layers.conv import BN_EPS, BN_MOMENTUM, ConvBNAct, make_activation
from slimseg.layers.fuse import Reparameterizable, fold_batchnorm


class RepConv(Reparameterizable):
    """Training: act(BN(conv3×3(x)) + BN(conv1×1(x)) [+ BN(x)]); fused: act(conv3×3(x) + b).

    Shapes: ``[B, c_in, H, W] → [B, c_out, H/s, W/s]``. The identity branch exists only when
    ``identity=True``, ``c_in == c_out`` and ``s == 1``. ``fused=True`` builds the fused form.
    """

    def __init__(
        self,
        c_in: int,
        c_out: int,
        s: int = 1,
        groups: int = 1,
        act: str | None = "silu",
        identity: bool = False,
        fused: bool = False,
    ) -> None:
        super().__init__()
        self.c_in, self.c_out, self.stride, self.groups = c_in, c_out, s, groups
        self.act = make_activation(act)
        self._fused = fused
        if fused:
            self.conv = nn.Conv2d(c_in, c_out, 3, s, 1, groups=groups, bias=True)
            return
        self.branch3 = ConvBNAct(c_in, c_out, 3, s, groups=groups, act=None)
        self.branch1 = ConvBNAct(c_in, c_out, 1, s, p=0, groups=groups, act=None)
        self.identity = (
            nn.BatchNorm2d(c_in, eps=BN_EPS, momentum=BN_MOMENTUM)
            if identity and c_in == c_out and s == 1
            else None
        )

    @property
    def is_fused(self) -> bool:
        return self._fused

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self._fused:
            return self.act(self.conv(x))
        y = self.branch3(x) + self.branch1(x)
        if self.identity is not None:
            y = y + self.identity(x)
        return self.act(y)

    @torch.no_grad()
    def fused_kernel(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Equivalent single 3×3 kernel ``[c_out, c_in/g, 3, 3]`` and bias ``[c_out]``."""
        w3, b3 = fold_batchnorm(self.branch3.conv.weight, None, self.branch3.bn)
        w1, b1 = fold_batchnorm(self.branch1.conv.weight, None, self.branch1.bn)
        weight = w3 + F.pad(w1, [1, 1, 1, 1])
        bias = b3 + b1
        if self.identity is not None:
            per_group = self.c_in // self.groups
            eye = torch.zeros_like(w3)
            idx = torch.arange(self.c_in, device=w3.device)
            eye[idx, idx % per_group, 1, 1] = 1.0
            wi, bi = fold_batchnorm(eye, None, self.identity)
            weight, bias = weight + wi, bias + bi
        return weight, bias

    def _reparameterize(self) -> None:
        """Merge the branches into one 3×3 conv in place."""
        weight, bias = self.fused_kernel()
        conv = nn.Conv2d(self.c_in, self.c_out, 3, self.stride, 1, groups=self.groups, bias=True)
        conv = conv.to(weight.device, weight.dtype)
        conv.weight.copy_(weight)
        conv.bias.copy_(bias)
        del self.branch3, self.branch1, self.identity
        self.conv = conv
        self._fused = True
