"""Conv2d → BatchNorm2d → activation, the building block of every slimseg network."""

from __future__ import annotations

import torch
from torch import nn

from slimseg.layers.fuse import Reparameterizable, fold_batchnorm

# Activation names accepted by specs and layers; None means identity (a linear layer).
ACTIVATIONS = {
    "silu": lambda: nn.SiLU(inplace=True),
    "leaky": lambda: nn.LeakyReLU(0.1, inplace=True),
    "relu": lambda: nn.ReLU(inplace=True),
}

# YOLOv8 BatchNorm settings (eps 1e-3, momentum 0.03); Darknet layers pass their own.
BN_EPS = 1e-3
BN_MOMENTUM = 0.03


def make_activation(name: str | None) -> nn.Module:
    """Return the activation module for ``name`` (``None`` → identity)."""
    if name is None:
        return nn.Identity()
    if name not in ACTIVATIONS:
        raise ValueError(f"unknown activation {name!r}; valid: {sorted(ACTIVATIONS)} or None")
    return ACTIVATIONS[name]()


class ConvBNAct(Reparameterizable):
    """Conv2d (no bias) → BatchNorm2d → activation; fused form: Conv2d (bias) → activation.

    Shapes: ``[B, c_in, H, W] → [B, c_out, H', W']`` with ``H' = floor((H + 2p - k) / s) + 1``.
    ``fused=True`` builds the fused form directly so fused checkpoints load.
    """

    def __init__(
        self,
        c_in: int,
        c_out: int,
        k: int = 1,
        s: int = 1,
        p: int | None = None,
        groups: int = 1,
        act: str | None = "silu",
        bn_eps: float = BN_EPS,
        bn_momentum: float = BN_MOMENTUM,
        fused: bool = False,
    ) -> None:
        super().__init__()
        padding = k // 2 if p is None else p
        self.conv = nn.Conv2d(c_in, c_out, k, s, padding, groups=groups, bias=fused)
        self.bn: nn.Module = (
            nn.Identity() if fused else nn.BatchNorm2d(c_out, eps=bn_eps, momentum=bn_momentum)
        )
        self.act = make_activation(act)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.bn(self.conv(x)))

    @property
    def is_fused(self) -> bool:
        return not isinstance(self.bn, nn.BatchNorm2d)

    def _reparameterize(self) -> None:
        """Fold the BatchNorm into the convolution in place."""
        weight, bias = fold_batchnorm(self.conv.weight, self.conv.bias, self.bn)
        old = self.conv
        conv = nn.Conv2d(
            old.in_channels,
            old.out_channels,
            old.kernel_size,
            old.stride,
            old.padding,
            dilation=old.dilation,
            groups=old.groups,
            bias=True,
        ).to(weight.device, weight.dtype)
        conv.weight.copy_(weight)
        conv.bias.copy_(bias)
        self.conv = conv
        self.bn = nn.Identity()
