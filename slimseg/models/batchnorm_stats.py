"""BatchNorm statistics of one batch: what a randomly initialised network needs before its
outputs depend on the image (smoke tests, benchmarks of untrained weights)."""

from __future__ import annotations

import torch
from torch import nn


def batchnorm_from(model: nn.Module, batch: torch.Tensor) -> nn.Module:
    """BatchNorm statistics of one ``batch [B, 3, H, W]`` (0-1 floats): unit-variance
    activations, so a randomly initialised network's outputs depend on the image (random init
    alone gives near-constant activations: equal scores, empty masks). Returns it in eval."""
    for m in model.modules():
        if isinstance(m, nn.BatchNorm2d):
            m.momentum = None
            m.reset_running_stats()
    model.train()
    with torch.no_grad():
        model(batch)
    return model.eval()
