"""Darknet19-YOLOv3: sizes, decoding, fusion and darknet .weights round trips."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from slimseg.layers.conv import ConvBNAct
from slimseg.layers.fuse import fuse_model
from slimseg.models.darknet_weights import (
    DarknetWeightsError,
    load_darknet_weights,
    read_darknet_header,
    save_darknet_weights,
)
from slimseg.models.darknet_yolov3 import STANDARD_ANCHORS, Darknet19YOLOv3
from slimseg.models.registry import build_model

N_CONVS = 41
N_BACKBONE_CONVS = 18


def n_params(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


@torch.no_grad()
def randomize(model: nn.Module, seed: int) -> nn.Module:
    """Give every parameter and BN statistic distinct, well-conditioned random values."""
    g = torch.Generator().manual_seed(seed)
    for m in model.modules():
        if isinstance(m, nn.BatchNorm2d):
            n = m.num_features
            m.weight.copy_(torch.rand(n, generator=g) + 0.5)
            m.bias.copy_(torch.rand(n, generator=g) - 0.5)
            m.running_mean.copy_(torch.rand(n, generator=g) - 0.5)
            m.running_var.copy_(torch.rand(n, generator=g) + 0.5)
        elif isinstance(m, nn.Conv2d):
            m.weight.copy_(torch.randn(m.weight.shape, generator=g) * 0.02)
            if m.bias is not None:
                m.bias.copy_(torch.randn(m.bias.shape, generator=g) * 0.1)
    return model


def meta_model(num_classes: int, fused: bool = False) -> Darknet19YOLOv3:
    """A weightless model for loads that must fail before any tensor is touched."""
    with torch.device("meta"):
        return build_model("darknet19-yolov3", num_classes=num_classes, fused=fused)


@pytest.fixture(scope="module")
def model() -> Darknet19YOLOv3:
    """Shared nc=1 model in eval mode; tests must not modify it (copy first)."""
    torch.manual_seed(0)
    return randomize(build_model("darknet19-yolov3", num_classes=1), seed=1).eval()


@pytest.fixture(scope="module")
def fused(model: Darknet19YOLOv3) -> Darknet19YOLOv3:
    return fuse_model(model)


@pytest.fixture(scope="module")
def weights_file(model: Darknet19YOLOv3, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("dn") / "full.weights"
    assert save_darknet_weights(model, path) == N_CONVS
    return path


def assert_state_equal(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k


# ----------------------------------------------------------------------------- structure


def test_param_counts(model: Darknet19YOLOv3) -> None:
    assert n_params(model.backbone) == 19_817_376
    assert n_params(model) == 40_756_182
    with torch.device("meta"):  # exact counts without initialising 40 M weights
        assert n_params(build_model("darknet19-yolov3", num_classes=20)) == 40_858_497
        assert n_params(build_model("darknet19-yolov3", num_classes=80)) == 41_181_597


def test_conv_order_matches_cfg(model: Darknet19YOLOv3) -> None:
    convs = model.darknet_convs()
    assert len(convs) == N_CONVS
    assert all(isinstance(c, ConvBNAct) for c in convs[:N_BACKBONE_CONVS])
    preds = [i for i, c in enumerate(convs) if isinstance(c, nn.Conv2d)]
    assert preds == [24, 32, 40]  # P5 pred, then lateral 256 at 25, P4 pred, lateral 128 at 33
    for i in preds:
        assert convs[i].out_channels == 18 and convs[i].kernel_size == (1, 1)
        assert convs[i].bias is not None
    assert (convs[25].conv.in_channels, convs[25].conv.out_channels) == (512, 256)
    assert (convs[33].conv.in_channels, convs[33].conv.out_channels) == (256, 128)
    assert convs[26].conv.in_channels == 256 + 512  # concat [upsampled, s16 tap]
    assert convs[34].conv.in_channels == 128 + 256  # concat [upsampled, s8 tap]
    widths = [c.conv.out_channels for c in convs[:N_BACKBONE_CONVS]]
    # darknet19.cfg convs 0, 2, 4-6, 8-10 | 12-16 | 18-22
    assert widths == [32, 64, 128, 64, 128, 256, 128, 256, 512, 256, 512, 256, 512] + [
        1024, 512, 1024, 512, 1024
    ]  # fmt: skip
    assert all(isinstance(c.act, nn.LeakyReLU) and c.act.negative_slope == 0.1 for c in convs[:24])


def test_anchors_and_strides(model: Darknet19YOLOv3) -> None:
    assert model.strides == (8, 16, 32)
    assert model.num_classes == 1
    assert model.anchors.tolist() == [[list(a) for a in level] for level in STANDARD_ANCHORS]


# ----------------------------------------------------------------------------- forward


def test_eval_shape_416(model: Darknet19YOLOv3) -> None:
    with torch.no_grad():
        y = model(torch.rand(1, 3, 416, 416))
    assert y.shape == (1, 6, 10_647)
    assert torch.isfinite(y).all()


def test_eval_shape_non_square(model: Darknet19YOLOv3) -> None:
    with torch.no_grad():
        assert model(torch.rand(1, 3, 320, 416)).shape == (1, 6, 3 * (40 * 52 + 20 * 26 + 10 * 13))
        y = model(torch.rand(2, 3, 96, 128))
    cells = sum((96 // s) * (128 // s) for s in (8, 16, 32))
    assert y.shape == (2, 6, 3 * cells)


def test_decode_hand_built(model: Darknet19YOLOv3) -> None:
    """Zero pred kernels make the output input-independent; check one anchor by hand."""
    m = copy.deepcopy(model)
    logit = lambda p: math.log(p / (1 - p))  # noqa: E731
    with torch.no_grad():
        for head in (m.head_p3, m.head_p4, m.head_p5):
            head.pred.weight.zero_()
            bias = head.pred.bias.view(3, 6)
            bias[:] = torch.tensor([0.0, logit(0.25), math.log(2.0), 0.0, logit(0.9), logit(0.3)])
        h, w = 96, 128
        y = m(torch.rand(1, 3, h, w))
    # stride 16 level, anchor 2 = (59, 119), cell row 3, col 5
    n8 = 3 * (h // 8) * (w // 8)
    col = n8 + 2 * (h // 16) * (w // 16) + 3 * (w // 16) + 5
    expected = [(5 + 0.5) * 16, (3 + 0.25) * 16, 2 * 59, 119, 0.9, 0.3]
    assert y[0, :, col].tolist() == pytest.approx(expected, rel=1e-6)
    # stride 8, anchor 0 = (10, 13), cell (0, 0) is the very first column
    assert y[0, :, 0].tolist() == pytest.approx([4.0, 2.0, 20.0, 13.0, 0.9, 0.3], rel=1e-6)

    # training mode: raw [B, na, 5+nc, H/s, W/s] per stride 8, 16, 32; anchor a, entry k is
    # predictor channel a·(5+nc) + k
    with torch.no_grad():
        for head in (m.head_p3, m.head_p4, m.head_p5):
            head.pred.bias.copy_(torch.arange(18.0))
        m.train()
        outs = m(torch.rand(2, 3, h, w))
    shapes = [tuple(o.shape) for o in outs]
    assert shapes == [(2, 3, 6, h // s, w // s) for s in (8, 16, 32)]
    assert torch.equal(outs[1][1, 2, :, 3, 5], torch.arange(12.0, 18.0))


# ----------------------------------------------------------------------------- fusion


def test_fused_matches_unfused(model: Darknet19YOLOv3, fused: Darknet19YOLOv3) -> None:
    assert model.head_p3.convs[0].bn.running_var.min() >= 0.5  # randomized BN statistics
    assert all(isinstance(c.bn, nn.Identity) for c in fused.darknet_convs()[:24:5])
    assert all(isinstance(c.bn, nn.BatchNorm2d) for c in model.darknet_convs()[:24:5])
    x = torch.rand(2, 3, 64, 96)
    with torch.no_grad():
        a, b = model(x), fused(x)
    assert (a[:, :4] - b[:, :4]).abs().max() <= 1e-3  # pixels
    assert (a[:, 4:] - b[:, 4:]).abs().max() <= 1e-5


def test_deploy_loads_fused_state_dict(fused: Darknet19YOLOv3) -> None:
    deploy = build_model("darknet19-yolov3", num_classes=1, fused=True).eval()
    deploy.load_state_dict(fused.state_dict(), strict=True)
    assert n_params(deploy) == n_params(fused) == 40_740_534
    x = torch.rand(1, 3, 64, 64)
    with torch.no_grad():
        assert torch.equal(deploy(x), fused(x))


# ----------------------------------------------------------------------------- .weights


@pytest.mark.parametrize("version", [(0, 1, 0), (0, 2, 0)])
def test_weights_round_trip(
    model: Darknet19YOLOv3, weights_file: Path, tmp_path: Path, version: tuple[int, int, int]
) -> None:
    if version == (0, 2, 0):
        path, seen = weights_file, 0
    else:
        path, seen = tmp_path / "v010.weights", 123_456
        save_darknet_weights(model, path, version=version, seen=seen)
    hdr_bytes = 20 if version >= (0, 2, 0) else 16
    assert read_darknet_header(path) == (version, seen, hdr_bytes)
    bn_channels = sum(m.num_features for m in model.modules() if isinstance(m, nn.BatchNorm2d))
    assert path.stat().st_size == hdr_bytes + 4 * (40_756_182 + 2 * bn_channels)
    fresh = build_model("darknet19-yolov3", num_classes=1)
    assert load_darknet_weights(fresh, path) == N_CONVS
    assert_state_equal(fresh.state_dict(), model.state_dict())


def test_backbone_only_file(model: Darknet19YOLOv3, tmp_path: Path) -> None:
    path = tmp_path / "darknet19.conv.23"
    assert save_darknet_weights(model, path, cutoff=N_BACKBONE_CONVS) == N_BACKBONE_CONVS
    target = build_model(
        "darknet19-yolov3", num_classes=1
    )  # default init differs from the fixture everywhere
    head_before = {k: v.clone() for k, v in target.state_dict().items() if "backbone" not in k}
    assert load_darknet_weights(target, path) == N_BACKBONE_CONVS
    state, ref = target.state_dict(), model.state_dict()
    for k, v in state.items():
        if "backbone" in k:
            assert torch.equal(v, ref[k]), k
        else:
            assert torch.equal(v, head_before[k]), k


def _prefix_file(src: Path, dst: Path, n_bytes: int, extra: bytes = b"") -> Path:
    with src.open("rb") as f:
        dst.write_bytes(f.read(n_bytes) + extra)
    return dst


def test_truncated_mid_layer(model: Darknet19YOLOv3, weights_file: Path, tmp_path: Path) -> None:
    conv0 = 4 * (4 * 32 + 32 * 3 * 3 * 3)
    path = _prefix_file(weights_file, tmp_path / "cut.weights", 20 + conv0 + 400)
    target = build_model("darknet19-yolov3", num_classes=1)
    before = copy.deepcopy(target.state_dict())
    with pytest.raises(DarknetWeightsError, match="conv 1") as err:
        load_darknet_weights(target, path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)
    assert_state_equal(target.state_dict(), before)  # failed load leaves the model alone
    # a clean conv boundary is a valid partial file
    ok = _prefix_file(weights_file, tmp_path / "one.weights", 20 + conv0)
    assert load_darknet_weights(target, ok) == 1


def test_trailing_garbage(model: Darknet19YOLOv3, weights_file: Path, tmp_path: Path) -> None:
    path = tmp_path / "extra.weights"
    path.write_bytes(weights_file.read_bytes() + np.zeros(3, "<f4").tobytes())
    with pytest.raises(DarknetWeightsError, match="12 trailing bytes") as err:
        load_darknet_weights(meta_model(1), path)
    assert str(path) in str(err.value)


def test_wrong_num_classes_hint(model: Darknet19YOLOv3, weights_file: Path) -> None:
    with pytest.raises(DarknetWeightsError, match="num_classes=1") as err:
        load_darknet_weights(meta_model(2), weights_file)
    assert str(weights_file) in str(err.value)


def test_short_header(tmp_path: Path) -> None:
    path = tmp_path / "short.weights"
    path.write_bytes(np.array([0, 2], "<i4").tobytes())
    with pytest.raises(DarknetWeightsError, match="too short") as err:
        load_darknet_weights(meta_model(1), path)
    assert str(path) in str(err.value)
    path.write_bytes(np.array([0, 2, 0, 0], "<i4").tobytes())  # 0.2 needs a uint64 seen
    with pytest.raises(DarknetWeightsError, match="needs 20 bytes"):
        load_darknet_weights(meta_model(1), path)


def test_fused_model_rejected(fused: Darknet19YOLOv3, weights_file: Path, tmp_path: Path) -> None:
    with pytest.raises(DarknetWeightsError, match="fused"):
        load_darknet_weights(meta_model(1, fused=True), weights_file)
    with pytest.raises(DarknetWeightsError, match="fused"):
        save_darknet_weights(fused, tmp_path / "f.weights")
    assert not list(tmp_path.iterdir())
