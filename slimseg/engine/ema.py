"""Exponential moving average of model weights (used for validation, checkpoints, export)."""

from __future__ import annotations

import copy
import math

import torch
from torch import nn


class ModelEMA:
    """Keeps ``ema = d·ema + (1 − d)·model`` with a ramped decay ``d = decay·(1 − e^(−n/tau))``.

    Floating-point parameters and buffers are averaged; integer buffers (BN step counters) are
    copied. The EMA model stays in eval mode and never requires gradients.
    """

    def __init__(self, model: nn.Module, decay: float = 0.9999, tau: float = 2000.0) -> None:
        self.module = copy.deepcopy(model).eval().requires_grad_(False)
        self.decay, self.tau = decay, tau
        self.updates = 0

    def current_decay(self) -> float:
        return self.decay * (1 - math.exp(-self.updates / self.tau))

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        self.updates += 1
        d = self.current_decay()
        live = model.state_dict()
        floats, sources, others, copies = [], [], [], []
        for name, value in self.module.state_dict().items():
            src = live[name].detach()
            if value.dtype.is_floating_point:
                floats.append(value)
                sources.append(src if src.dtype == value.dtype else src.to(value.dtype))
            else:
                others.append(value)
                copies.append(src)
        # the same two element-wise operations as value.mul_(d).add_(src, alpha=1 - d), one
        # fused kernel launch per group instead of two per tensor
        if floats:
            torch._foreach_mul_(floats, d)
            torch._foreach_add_(floats, sources, alpha=1 - d)
        for value, src in zip(others, copies, strict=True):
            value.copy_(src)

    def state_dict(self) -> dict:
        return {"module": self.module.state_dict(), "updates": self.updates}

    def load_state_dict(self, state: dict) -> None:
        self.module.load_state_dict(state["module"])
        self.updates = int(state["updates"])
