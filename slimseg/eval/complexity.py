"""Model size and cost: params, gradients, GFLOPs in our convention and the paper's.

Ours: ``torch.utils.flop_counter.FlopCounterMode`` on an eval-mode forward of a batch-1
``imgsz × imgsz`` input (2 × multiply-adds of convolutions and matmuls). Matmuls include
MSNET's attention products ``q @ kᵀ`` and ``attn @ v``: its attention is written with plain
``torch.matmul`` (no fused attention kernel), which dispatches to ``aten.bmm``, an op the
counter counts, so no extra hook is needed (``tests/models/test_msnet.py`` checks the count against
the closed form). Softmax, LayerNorm, GELU and resizing are not counted (as activations and
BatchNorm are not).
Paper convention (the thop-based counter the substation paper used): the same, except that
every ConvTranspose2d is counted as ``out_elems · c_in/g · k²`` multiply-adds instead of
``in_elems · c_out/g · k²``, and every BatchNorm2d adds 4 operations per output element
(2 × 4 FLOPs per element in our 2×MAC units).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn
from torch.utils.flop_counter import FlopCounterMode

from slimseg.layers.fuse import fuse_model
from slimseg.models.base import ZooModel


@dataclass(frozen=True)
class Complexity:
    """Size and cost of one model at one input size."""

    params: int
    gradients: int
    gflops: float
    gflops_paper: float
    fused_params: int
    fused_gflops: float
    dead_params: int
    imgsz: tuple[int, int]

    @property
    def params_paper(self) -> int:
        """Params counted as the paper did (with the original code's unused conv)."""
        return self.params + self.dead_params

    def to_dict(self) -> dict:
        return {**asdict(self), "imgsz": list(self.imgsz), "params_paper": self.params_paper}


def count_params(model: nn.Module) -> tuple[int, int]:
    """``(all parameters, parameters with requires_grad)``."""
    total = sum(p.numel() for p in model.parameters())
    grads = sum(p.numel() for p in model.parameters() if p.requires_grad)
    return total, grads


def _probe(model: nn.Module, imgsz: tuple[int, int]) -> torch.Tensor:
    p = next(model.parameters())
    return torch.zeros(1, 3, *imgsz, device=p.device, dtype=p.dtype)


@torch.no_grad()
def measure_flops(model: nn.Module, imgsz: tuple[int, int] = (640, 640)) -> tuple[float, float]:
    """``(GFLOPs ours, GFLOPs paper convention)`` of an eval-mode forward at batch 1."""
    was_training = model.training
    model.eval()
    extra = 0.0
    hooks = []

    def on_bn(_m: nn.Module, _i: tuple, out: torch.Tensor) -> None:
        nonlocal extra
        extra += 8.0 * out.numel()

    def on_convt(m: nn.ConvTranspose2d, inp: tuple, out: torch.Tensor) -> None:
        nonlocal extra
        k = math.prod(m.kernel_size)
        ours = inp[0].numel() * (m.out_channels // m.groups) * k
        theirs = out.numel() * (m.in_channels // m.groups) * k
        extra += 2.0 * (theirs - ours)

    for m in model.modules():
        if isinstance(m, nn.BatchNorm2d):
            hooks.append(m.register_forward_hook(on_bn))
        elif isinstance(m, nn.ConvTranspose2d):
            hooks.append(m.register_forward_hook(on_convt))
    try:
        counter = FlopCounterMode(display=False)
        with counter:
            model(_probe(model, imgsz))
    finally:
        for h in hooks:
            h.remove()
        model.train(was_training)
    ours = counter.get_total_flops() / 1e9
    return ours, ours + extra / 1e9


def measure(model: ZooModel, imgsz: int | tuple[int, int] = 640) -> Complexity:
    """Params, gradients and GFLOPs of ``model`` as built and of its fused copy."""
    size = (imgsz, imgsz) if isinstance(imgsz, int) else tuple(imgsz)
    params, grads = count_params(model)
    gflops, gflops_paper = measure_flops(model, size)
    fused = fuse_model(model)
    fused_params, _ = count_params(fused)
    fused_gflops, _ = measure_flops(fused, size)
    dead = model.dead_conv_params()
    return Complexity(
        params=params,
        gradients=grads,
        gflops=round(gflops, 4),
        gflops_paper=round(gflops_paper, 4),
        fused_params=fused_params,
        fused_gflops=round(fused_gflops, 4),
        dead_params=dead,
        imgsz=size,
    )
