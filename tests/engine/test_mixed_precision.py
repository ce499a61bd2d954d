"""Float32 where it matters under autocast: mask assembly, the eval forward's decode, and the
validation step of a run trained with ``16-mixed``/``bf16-mixed`` (CPU autocast stands in
for CUDA's; the dtype rules are the same)."""

from __future__ import annotations

import pytest
import torch
from conftest import batchnorm_from, open_class_bias

from slimseg.engine.module import ZooModule
from slimseg.eval.validation import detect_batch
from slimseg.models.registry import build_model, get_spec
from slimseg.ops.letterbox import letterbox_params
from slimseg.ops.masks import assemble_masks

LOW = (torch.bfloat16, torch.float16)


@pytest.mark.parametrize("dtype", LOW)
@pytest.mark.parametrize("threshold", [None, 0.5])
def test_assemble_masks_under_autocast_equals_float32(
    dtype: torch.dtype, threshold: float | None
) -> None:
    g = torch.Generator().manual_seed(0)
    coeffs, proto = torch.randn(5, 8, generator=g), torch.randn(8, 16, 16, generator=g)
    boxes = torch.tensor([[2, 3, 40, 50], [0, 0, 64, 64], [10, 10, 12, 30], [5, 5, 6, 6]] * 2)
    boxes = boxes[:5].float()
    ref = assemble_masks(coeffs, proto, boxes, (64, 64), threshold=threshold)
    with torch.autocast("cpu", dtype=dtype):
        got = assemble_masks(coeffs, proto, boxes, (64, 64), threshold=threshold)
    assert got.dtype == ref.dtype
    assert torch.equal(got, ref)


@pytest.mark.parametrize("name", ["yolov8n-seg", "darknet19-yolov3"])
@pytest.mark.parametrize("dtype", LOW)
def test_eval_forward_decodes_in_float32(name: str, dtype: torch.dtype) -> None:
    model = build_model(name, 3).eval()
    x = torch.rand(1, 3, 96, 96)
    with torch.autocast("cpu", dtype=dtype):
        out = model(x)
    pred, proto = out if isinstance(out, tuple) else (out, None)
    assert pred.dtype == torch.float32
    assert proto is None or proto.dtype == torch.float32


def _batch(n: int = 2, imgsz: int = 96) -> dict:
    g = torch.Generator().manual_seed(1)
    images = torch.randint(0, 256, (n, 3, imgsz, imgsz), dtype=torch.uint8, generator=g)
    meta = [{"letterbox": letterbox_params(72, 96, imgsz), "orig_shape": (72, 96)}] * n
    return {"images": images, "image_ids": list(range(n)), "meta": meta}


@pytest.mark.parametrize("dtype", LOW)
def test_validation_step_under_autocast_equals_float32_validation(dtype: torch.dtype) -> None:
    """Lightning wraps validation_step in the training autocast: the scored detections must be
    those of ``slimseg val`` (float32), or in-training mAP and best.pt follow the precision."""
    spec = get_spec("yolov8n-seg", 3).to_dict()
    module = ZooModule(spec, {"ema": False, "conf": 0.001}, ["a", "b", "c"])
    batch = _batch()
    batchnorm_from(module.model, batch["images"].float() / 255)
    open_class_bias(module.model)
    ref = detect_batch(module.model.eval(), batch, conf=0.001)
    with torch.autocast("cpu", dtype=dtype):
        module.validation_step(batch, 0)
    ((ids, frames),) = module._val_results
    assert ids == [0, 1] and len(frames) == len(ref)
    assert sum(len(f.scores) for f in ref) > 0
    for got, want in zip(frames, ref, strict=True):
        assert (got.boxes == want.boxes).all() and (got.scores == want.scores).all()
        assert got.rles == want.rles
