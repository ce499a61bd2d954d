"""Re-parameterisation protocol: BatchNorm folding and the model-wide fuse walker.

A module takes part in fusion by defining ``reparameterize()``, which rewrites it in place
into its deploy form (the same structure ``deploy=True`` builds). ``fuse_model`` applies it
top-down on a copy, so a block handles its own children (RepConv folds its branches).
"""

from __future__ import annotations

import copy

import torch
from torch import nn


@torch.no_grad()
def fold_batchnorm(
    weight: torch.Tensor, bias: torch.Tensor | None, bn: nn.BatchNorm2d
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fold an eval-mode BatchNorm into the preceding conv.

    ``weight [c_out, c_in/g, kh, kw]``, ``bias [c_out]`` or None → fused ``(weight, bias)``.
    """
    std = torch.sqrt(bn.running_var + bn.eps)
    gain = bn.weight / std
    fused_w = weight * gain.reshape(-1, 1, 1, 1)
    conv_b = bias if bias is not None else torch.zeros_like(bn.running_mean)
    fused_b = bn.bias + (conv_b - bn.running_mean) * gain
    return fused_w, fused_b


def _reparameterize_tree(module: nn.Module) -> None:
    if hasattr(module, "reparameterize"):
        module.reparameterize()
    for child in module.children():
        _reparameterize_tree(child)


def fuse_model(model: nn.Module) -> nn.Module:
    """Return a fused deep copy of ``model`` in eval mode; ``model`` is left untouched."""
    fused = copy.deepcopy(model).eval()
    _reparameterize_tree(fused)
    return fused
