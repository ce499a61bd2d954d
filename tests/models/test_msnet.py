"""MSNET: shapes at several input sizes, pinned size and cost, attention, training, export."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from conftest import measured, randomize_batchnorm
from torch import nn
from torch.utils.flop_counter import FlopCounterMode

import slimseg
from slimseg.deploy.onnx_export import export_onnx
from slimseg.deploy.predictor import Predictor, combined_mask
from slimseg.deploy.trt_ops import DATA_DEPENDENT_OPS, TENSORRT_SUPPORTED_OPS
from slimseg.losses.semantic import SemanticLoss
from slimseg.models.msnet.attention import Attention
from slimseg.models.msnet.backbone import resize_pos_embed
from slimseg.models.registry import get_spec
from slimseg.models.specs import SpecError, load_spec
from slimseg.utils.shipped import shipped_dir

# measured with slimseg.eval.complexity.measure (nc 20, 640 x 640, batch 1), then pinned
PINNED = {
    "msnet-t": (978_780, 3.0048),
    "msnet-s": (20_126_428, 51.4214),
}


@pytest.mark.parametrize(("h", "w"), [(320, 320), (256, 384)])
def test_logits_shape_at_two_input_sizes(h: int, w: int) -> None:
    model = slimseg.build_model("msnet-t", num_classes=7)
    x = torch.rand(2, 3, h, w)
    assert model(x).shape == (2, 8, h, w)  # training mode: the same tensor
    with torch.no_grad():
        assert model.eval()(x).shape == (2, 8, h, w)


def test_position_embedding_resizes_only_when_needed() -> None:
    pos = torch.randn(1, 4, 10, 10)
    same = resize_pos_embed(pos, (10, 10))
    assert torch.equal(same, pos.flatten(2).transpose(1, 2))
    other = resize_pos_embed(pos, (8, 12))
    assert other.shape == (1, 96, 4)
    # constant embeddings stay constant under bilinear resizing
    flat = resize_pos_embed(torch.ones(1, 4, 10, 10), (5, 7))
    assert torch.allclose(flat, torch.ones_like(flat))


@pytest.mark.parametrize(
    "name",
    ["msnet-t", pytest.param("msnet-s", marks=pytest.mark.slow)],  # msnet-s: ~12 s
)
def test_params_and_gflops_pinned(name: str) -> None:
    c = measured(slimseg.build_model(name, num_classes=20), 640)
    params, gflops = PINNED[name]
    assert c.params == params and c.gradients == params
    assert c.gflops == pytest.approx(gflops, abs=5e-4)
    assert c.fused_params < c.params  # BatchNorms folded


def test_attention_matches_reference_and_its_matmuls_are_counted() -> None:
    attn = Attention(32, 4).eval()
    q, kv = torch.randn(2, 5, 32), torch.randn(2, 9, 32)
    with torch.no_grad():
        got = attn(q, kv)
        ref = torch.nn.functional.scaled_dot_product_attention(
            attn._split(attn.q(q)), attn._split(attn.k(kv)), attn._split(attn.v(kv))
        )
        ref = attn.proj(ref.transpose(1, 2).reshape(2, 5, 32))
    assert torch.allclose(got, ref, atol=1e-5)
    counter = FlopCounterMode(display=False)
    with counter, torch.no_grad():
        attn(q, kv)
    linears = 2 * 2 * 32 * 32 * (5 + 9 + 9 + 5)  # q, k, v, proj projections
    matmuls = 2 * 2 * (2 * 4 * 5 * 9 * 8)  # q @ k^T and attn @ v over 4 heads of 8
    assert counter.get_total_flops() == linears + matmuls


def _blobs(n: int, size: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Images with a bright square of class 1 or a dark disc of class 2 on noise."""
    g = np.random.default_rng(seed)
    images = g.random((n, 3, size, size), dtype=np.float32) * 0.3 + 0.35
    target = np.zeros((n, size, size), np.int64)
    yy, xx = np.mgrid[:size, :size]
    for i in range(n):
        cy, cx = g.integers(size // 4, 3 * size // 4, 2)
        r = size // 6
        if i % 2:
            sel = (abs(yy - cy) < r) & (abs(xx - cx) < r)
            images[i][:, sel] = 0.95
            target[i][sel] = 1
        else:
            sel = (yy - cy) ** 2 + (xx - cx) ** 2 < r**2
            images[i][:, sel] = 0.05
            target[i][sel] = 2
    return torch.from_numpy(images), torch.from_numpy(target)


def test_loss_decreases_on_generated_data() -> None:
    model = slimseg.build_model("msnet-t", num_classes=2)
    images, target = _blobs(4, 64, seed=0)
    loss_fn = SemanticLoss()
    opt = torch.optim.AdamW(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(12):
        loss, _ = loss_fn(model(images), target)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.7 * losses[0], losses


def test_spec_fields_are_strict(tmp_path: Path) -> None:
    text = (shipped_dir("models") / "msnet-t.yaml").read_text()
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("hidden: 64", "hidden: 64\n  width: 2"))
    with pytest.raises(SpecError, match=r"width.*valid fields"):
        load_spec(bad)
    bad.write_text(text.replace("heads: [1, 1, 2, 4]", "heads: [1, 1, 5, 4]"))
    with pytest.raises(SpecError, match="divisible"):
        load_spec(bad)
    bad.write_text(text.replace("task: semantic", "task: segment"))
    with pytest.raises(SpecError, match="semantic"):
        load_spec(bad)
    yolo = (shipped_dir("models") / "yolov8n.yaml").read_text()
    bad.write_text(yolo + "msnet: " + text.split("msnet:")[1].split("description")[0])
    with pytest.raises(SpecError, match="msnet"):
        load_spec(bad)


def test_spec_round_trips_and_other_families_keep_their_hash() -> None:
    spec = get_spec("msnet-s", 20)
    assert spec.msnet is not None and spec.msnet.token_stride == 16
    again = slimseg.models.specs.spec_from_mapping(type(spec), spec.to_dict(), "x")
    assert again == spec and again.hash == spec.hash
    assert "msnet" not in get_spec("yolov8n-seg").to_dict()
    assert get_spec("yolov8s-seg-gs-rep").hash == "358d59300ff7"  # as before msnet existed
    changed = dataclasses.replace(spec, msnet=dataclasses.replace(spec.msnet, hidden=128))
    assert changed.hash != spec.hash


def _realistic(nc: int = 4) -> nn.Module:
    """Random BN statistics and spread-out class biases: logits of a few units, not ~0."""
    model = randomize_batchnorm(slimseg.build_model("msnet-t", num_classes=nc)).eval()
    with torch.no_grad():
        model.class_bias.copy_(torch.linspace(-1, 1, nc + 1))
        model.scale = 1.0
    return model


@pytest.mark.slow
def test_export_parity_tensorrt_ops_and_predictor(tmp_path: Path) -> None:
    model = _realistic()
    names = ["a", "b", "c", "d"]
    report = export_onnx(model, tmp_path / "m.onnx", (128, 160), names, [1.0, 0.0, 1.0, 0.0])
    assert set(report.ops) <= TENSORRT_SUPPORTED_OPS, set(report.ops) - TENSORRT_SUPPORTED_OPS
    assert not set(report.ops) & DATA_DEPENDENT_OPS
    assert "MatMul" in report.ops and "Softmax" in report.ops
    assert report.parity["input1/logit"] <= 1e-3 and report.parity["input1/class_agreement"] == 1
    proto = onnx.load(str(report.path))
    assert [o.name for o in proto.graph.output] == ["logits"]
    dims = [d.dim_value for d in proto.graph.output[0].type.tensor_type.shape.dim]
    assert dims == [1, 5, 128, 160]
    half = export_onnx(model, tmp_path / "h.onnx", (128, 160), half=True)
    assert half.parity["input1/class_agreement"] >= 0.99
    # the predictor gives a class map on the source frame, the same from ONNX as from torch
    predictor = Predictor.from_path(report.path)
    frame = (np.random.default_rng(0).random((100, 150, 3)) * 255).astype(np.uint8)
    pred = predictor.predict(frame)
    assert pred.class_map is not None and pred.class_map.shape == (100, 150)
    assert pred.class_map.dtype == np.uint8 and pred.class_map.max() <= 4 and len(pred) == 0
    torch_pred = Predictor(
        _torch_runner(model),
        predictor.metadata,
        (128, 160),
        "torch",
    ).predict(frame)
    assert (torch_pred.class_map == pred.class_map).mean() > 0.999
    mask = combined_mask(pred, ["a", 2])  # names and ids both select classes
    assert ((mask == 255) == np.isin(pred.class_map, [1, 3])).all()


def _torch_runner(model: nn.Module):
    from slimseg.deploy.runners import TorchRunner

    return TorchRunner(model.fuse())
