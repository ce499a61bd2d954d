"""Fused (deploy) models must compute what the trained models compute."""

from __future__ import annotations

import pytest
import torch
from conftest import randomize_batchnorm
from torch import nn

from slimseg.layers.conv import ConvBNAct
from slimseg.layers.fuse import fuse_model
from slimseg.layers.gsconv import GSConv, VoVGSCSP
from slimseg.layers.rep import RepConv
from slimseg.models.registry import build_model, list_models

YOLO_VARIANTS = [n for n in list_models() if n.startswith("yolov8")]


def _check_block(block: nn.Module, c_in: int, size: int = 12) -> None:
    block = randomize_batchnorm(block).double().eval()
    x = torch.randn(2, c_in, size, size + 4, dtype=torch.float64)
    fused = fuse_model(block)
    assert not any(isinstance(m, nn.BatchNorm2d) for m in fused.modules())
    with torch.no_grad():
        torch.testing.assert_close(fused(x), block(x), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize(
    "block",
    [
        lambda: ConvBNAct(6, 8, 3, 2),
        lambda: ConvBNAct(8, 8, 5, 1, groups=8, act=None),
        lambda: ConvBNAct(6, 10, 1, act="leaky"),
        lambda: RepConv(6, 8),
        lambda: RepConv(8, 8, identity=True),
        lambda: RepConv(8, 8, s=2, groups=2, identity=True),
        lambda: RepConv(8, 8, groups=4, identity=True),
        lambda: GSConv(6, 8, 3, 2),
        lambda: VoVGSCSP(8, 12, n=2),
    ],
)
def test_block_fusion_is_exact(block) -> None:
    module = block()
    c_in = next(m for m in module.modules() if isinstance(m, nn.Conv2d)).in_channels
    _check_block(module, c_in)


def test_repconv_fused_kernel_reproduces_branches() -> None:
    rep = randomize_batchnorm(RepConv(4, 4, identity=True)).double().eval()
    assert rep.identity is not None
    rep.reparameterize()
    assert rep.is_fused and not hasattr(rep, "branch3")
    assert [n for n, _ in rep.named_parameters()] == ["conv.weight", "conv.bias"]


def _unsaturate(model: nn.Module) -> None:
    """Zero the class-logit biases so scores sit near 0.5, where differences show."""
    with torch.no_grad():
        detect = model.detect
        heads = detect.cls if isinstance(detect.cls, nn.ModuleList) else [detect.cls]
        for h in heads:
            last = h[-1] if isinstance(h, nn.Sequential) else h
            last.bias.zero_()


@pytest.mark.parametrize("name", YOLO_VARIANTS)
def test_variant_fusion_matches(name: str) -> None:
    nc = 20
    model = randomize_batchnorm(build_model(name, num_classes=nc)).eval()
    _unsaturate(model)
    fused = model_fused = fuse_model(model)
    assert not any(isinstance(m, nn.BatchNorm2d) for m in fused.modules())
    x = torch.rand(2, 3, 160, 224)
    with torch.no_grad():
        ref, got = model(x), model_fused(x)
    ref_pred, got_pred = (ref[0], got[0]) if isinstance(ref, tuple) else (ref, got)
    assert (got_pred[:, :4] - ref_pred[:, :4]).abs().max() <= 1e-3  # px
    assert (got_pred[:, 4 : 4 + nc] - ref_pred[:, 4 : 4 + nc]).abs().max() <= 1e-5
    assert ref_pred[:, 4 : 4 + nc].std() > 0.01  # scores are not saturated
    if isinstance(ref, tuple):
        torch.testing.assert_close(got_pred[:, 4 + nc :], ref_pred[:, 4 + nc :], atol=1e-4, rtol=0)
        torch.testing.assert_close(got[1], ref[1], atol=1e-4, rtol=0)


@pytest.mark.parametrize("name", ["yolov8n-seg", "yolov8n-seg-gs-rep", "darknet19-yolov3"])
def test_fused_state_dict_loads_into_deploy_build(name: str) -> None:
    model = randomize_batchnorm(build_model(name, num_classes=3)).eval()
    fused = fuse_model(model)
    deploy = build_model(name, num_classes=3, fused=True).eval()
    deploy.load_state_dict(fused.state_dict(), strict=True)
    x = torch.rand(1, 3, 96, 128)
    with torch.no_grad():
        a, b = fused(x), deploy(x)
    a = a[0] if isinstance(a, tuple) else a
    b = b[0] if isinstance(b, tuple) else b
    torch.testing.assert_close(a, b, atol=0, rtol=0)


def test_fuse_leaves_original_untouched() -> None:
    model = build_model("yolov8n-seg-rep", num_classes=2)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    fuse_model(model)
    after = model.state_dict()
    assert before.keys() == after.keys()
    assert all(torch.equal(before[k], after[k]) for k in before)


@pytest.mark.parametrize("name", ["yolov8n-seg-gs-rep", "darknet19-yolov3"])
def test_model_fuse_method_returns_new_fused_model(name: str) -> None:
    model = build_model(name, num_classes=2)
    fused = model.fuse()
    assert fused is not model and not fused.training
    assert any(isinstance(m, nn.BatchNorm2d) for m in model.modules())
    assert not any(isinstance(m, nn.BatchNorm2d) for m in fused.modules())


def test_every_family_has_a_builder() -> None:
    from slimseg.models.registry import BUILDERS
    from slimseg.models.specs import FAMILIES

    assert set(BUILDERS) == set(FAMILIES)


@pytest.mark.parametrize("name", ["yolov8n-seg-gs-rep", "darknet19-yolov3", "msnet-t"])
def test_fused_state_is_the_blocks_own(name: str) -> None:
    from slimseg.models.base import ZooModel

    model = build_model(name, num_classes=2)
    assert isinstance(model, ZooModel) and model.spec.name == name
    assert not model.is_fused
    assert model.fuse().is_fused and build_model(name, num_classes=2, fused=True).is_fused
    assert not model.is_fused  # fuse() works on a copy


def test_reparameterize_refused_in_training_mode() -> None:
    rep = RepConv(4, 4).train()
    with pytest.raises(RuntimeError, match="training mode"):
        rep.reparameterize()
    conv = ConvBNAct(4, 4, 3).train()
    with pytest.raises(RuntimeError, match="eval"):
        conv.reparameterize()
    assert not rep.is_fused and not conv.is_fused
