"""Learning-rate and momentum schedule: warmup, then linear or cosine decay (per iteration)."""

from __future__ import annotations

import math

import numpy as np

from slimseg.engine.config import TrainConfig


def lr_factor(epoch_progress: float, cfg: TrainConfig) -> float:
    """Decay factor at a fractional epoch ``e``: 1 → ``lrf`` over ``cfg.epochs`` epochs."""
    x = min(max(epoch_progress / cfg.epochs, 0.0), 1.0)
    if cfg.cos_lr:
        return ((1 - math.cos(x * math.pi)) / 2) * (cfg.lrf - 1) + 1
    return (1 - x) * (1.0 - cfg.lrf) + cfg.lrf


def warmup_values(
    step: int, warmup_steps: int, target_lr: float, is_bias: bool, cfg: TrainConfig
) -> tuple[float, float | None]:
    """``(lr, momentum)`` during warmup: biases fall from ``warmup_bias_lr``, other groups
    rise from 0, momentum rises from ``warmup_momentum``; ``momentum`` is None after warmup."""
    if step >= warmup_steps:
        return target_lr, None
    start = cfg.warmup_bias_lr if is_bias else 0.0
    lr = float(np.interp(step, [0, warmup_steps], [start, target_lr]))
    momentum = float(np.interp(step, [0, warmup_steps], [cfg.warmup_momentum, cfg.momentum]))
    return lr, momentum
