"""ModelEMA: the grouped update computes exactly the per-tensor rule."""

from __future__ import annotations

import copy
import math

import torch
from torch import nn

from slimseg.engine.ema import ModelEMA


def _net() -> nn.Module:
    torch.manual_seed(0)
    return nn.Sequential(nn.Conv2d(3, 8, 3), nn.BatchNorm2d(8), nn.SiLU(), nn.Conv2d(8, 4, 1))


def test_update_is_bitwise_the_per_tensor_rule() -> None:
    model = _net()
    ema = ModelEMA(model, decay=0.9, tau=3.0)
    expected = copy.deepcopy(ema.module).state_dict()
    for step in range(1, 4):
        with torch.no_grad():
            for p in model.parameters():
                p.add_(torch.randn_like(p))
        model.train()(torch.randn(2, 3, 8, 8))  # moves BN statistics and its step counter
        ema.update(model)
        d = 0.9 * (1 - math.exp(-step / 3.0))
        for name, value in model.state_dict().items():
            if value.dtype.is_floating_point:
                expected[name].mul_(d).add_(value, alpha=1 - d)
            else:
                expected[name].copy_(value)
    for name, value in ema.module.state_dict().items():
        assert torch.equal(value, expected[name]), name
    assert int(ema.module[1].num_batches_tracked) == 3
