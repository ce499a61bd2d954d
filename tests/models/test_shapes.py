"""Output layouts of every YOLOv8 variant, eval and training mode, square and non-square."""

from __future__ import annotations

import pytest
import torch

from slimseg.models.registry import build_model, list_models
from slimseg.models.yolo import RawOutputs

YOLO_VARIANTS = [n for n in list_models() if n.startswith("yolov8")]


def anchors(h: int, w: int) -> int:
    return sum((h // s) * (w // s) for s in (8, 16, 32))


@pytest.mark.parametrize("name", YOLO_VARIANTS)
@pytest.mark.parametrize(("h", "w"), [(256, 320), (192, 96)])
def test_eval_layout_non_square(name: str, h: int, w: int) -> None:
    nc = 20
    model = build_model(name, num_classes=nc).eval()
    with torch.no_grad():
        out = model(torch.rand(2, 3, h, w))
    if model.spec.task == "segment":
        pred, proto = out
        assert pred.shape == (2, 4 + nc + 32, anchors(h, w))
        stride = model.spec.head.proto_stride  # 4, or 2 for the -hr variants
        assert proto.shape == (2, 32, h // stride, w // stride)
    else:
        assert out.shape == (2, 4 + nc, anchors(h, w))
        pred = out
    scores = pred[:, 4 : 4 + nc]
    assert torch.all((scores >= 0) & (scores <= 1))
    assert torch.all(pred[:, 2:4] > 0)  # widths and heights


@pytest.mark.parametrize("name", ["yolov8s-seg", "yolov8n-seg-gs-rep"])
def test_eval_layout_640(name: str) -> None:
    model = build_model(name, num_classes=20).eval()
    with torch.no_grad():
        pred, proto = model(torch.zeros(1, 3, 640, 640))
    assert pred.shape == (1, 56, 8400)
    assert proto.shape == (1, 32, 160, 160)


def test_boxes_are_in_input_pixels() -> None:
    """Zero box logits decode to a box centred on each anchor cell, width 2·7.5·stride."""
    model = build_model("yolov8n-seg", num_classes=3).eval()
    raw = model.forward_raw(torch.zeros(1, 3, 64, 96))
    zeros = [torch.zeros_like(f) for f in raw.feats]
    pred = model.decode(RawOutputs(zeros, raw.mask_coeffs, raw.proto))
    # first anchor: stride 8, cell (0, 0) → centre (4, 4); uniform bins → mean 7.5 per side
    assert pred[0, :4, 0].tolist() == pytest.approx([4.0, 4.0, 120.0, 120.0])
    # last anchor: stride 32, cell (row 1, col 2) of a 2x3 grid → centre (80, 48)
    assert pred[0, :4, -1].tolist() == pytest.approx([80.0, 48.0, 480.0, 480.0])
    assert pred[0, 4:7].unique().tolist() == [0.5]


@pytest.mark.parametrize("name", ["yolov8n-seg", "yolov8n-seg-gs-rep", "yolov8n"])
def test_training_outputs_and_gradients_reach_every_parameter(name: str) -> None:
    nc = 4
    model = build_model(name, num_classes=nc).train()
    raw = model(torch.rand(2, 3, 128, 160))
    assert isinstance(raw, RawOutputs)
    assert [tuple(f.shape) for f in raw.feats] == [
        (2, 64 + nc, 128 // s, 160 // s) for s in (8, 16, 32)
    ]
    loss = sum(f.square().mean() for f in raw.feats)
    if raw.proto is not None:
        assert raw.mask_coeffs.shape == (2, 32, anchors(128, 160))
        assert raw.proto.shape == (2, 32, 32, 40)
        loss = loss + raw.mask_coeffs.square().mean() + raw.proto.square().mean()
    loss.backward()
    missing = [n for n, p in model.named_parameters() if p.requires_grad and p.grad is None]
    assert missing == []
    frozen = [n for n, p in model.named_parameters() if not p.requires_grad]
    assert frozen == ["dfl.proj.weight"]
