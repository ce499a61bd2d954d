"""Re-parameterisation protocol: BatchNorm folding, the fused state and the model-wide walker.

Vocabulary (one meaning each across the package): *fuse* = fold BatchNorm into convolutions
and merge RepConv branches for inference; a block built with ``fused=True`` has the inference
structure from the start (so fused checkpoints load). Eq. 4's seg/box mask fusion of the
substation paper is a different idea and lives in ``slimseg.dynamic``.

A block takes part by subclassing ``Reparameterizable``: it declares its own state
(``is_fused``) and implements ``_reparameterize()``, which rewrites it in place into its fused
form (the same structure ``fused=True`` builds). ``fuse_model`` applies it top-down on a copy,
so a block handles its own children (RepConv folds its branches). ``is_fused(model)`` asks the
blocks, never guesses from the presence of BatchNorm layers.
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


class Reparameterizable(nn.Module):
    """A block with a training structure and an equivalent fused (inference) structure."""

    @property
    def is_fused(self) -> bool:
        """True when the block holds its fused structure."""
        raise NotImplementedError

    def _reparameterize(self) -> None:
        """Rewrite the block in place into its fused structure (called unfused, in eval mode)."""
        raise NotImplementedError

    @torch.no_grad()
    def reparameterize(self) -> None:
        """Fuse in place; a no-op when already fused. Refused in training mode: folding uses the
        BatchNorm running statistics, which training-mode forward passes do not use."""
        if self.is_fused:
            return
        if self.training:
            raise RuntimeError(
                f"{type(self).__name__}.reparameterize() in training mode: call .eval() first "
                "(fusing folds the BatchNorm running statistics)"
            )
        self._reparameterize()


def _reparameterize_tree(module: nn.Module) -> None:
    if isinstance(module, Reparameterizable):
        module.reparameterize()
    for child in module.children():
        _reparameterize_tree(child)


def is_fused(model: nn.Module) -> bool:
    """Whether every re-parameterizable block of ``model`` holds its fused structure.

    A model without such blocks is not fused. A partly fused model (some blocks fused, some
    not) is an error: no slimseg code path builds one."""
    states = {m.is_fused for m in model.modules() if isinstance(m, Reparameterizable)}
    if len(states) > 1:
        raise ValueError(f"{type(model).__name__} is partly fused; fuse_model() a fresh copy")
    return states == {True}


def fuse_model(model: nn.Module) -> nn.Module:
    """Return a fused deep copy of ``model`` in eval mode; ``model`` is left untouched."""
    fused = copy.deepcopy(model).eval()
    _reparameterize_tree(fused)
    return fused
