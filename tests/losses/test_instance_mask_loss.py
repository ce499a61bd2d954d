"""The instance-mask term at prototype and at input resolution, Dice and thin-part weights."""

from __future__ import annotations

import math

import pytest
import torch

from slimseg.losses.instance_mask import InstanceMaskLoss, target_mask_ratio, thin_parts
from slimseg.models.registry import get_spec
from slimseg.models.specs import MaskLossSpec, SpecError
from slimseg.ops.assign import Assignment


def _one_instance(box: list[float], anchors: int = 1) -> tuple[Assignment, torch.Tensor]:
    """``anchors`` foreground anchors of image 0, all assigned to GT slot 0 (row 0)."""
    fg = torch.ones(1, anchors, dtype=torch.bool)
    gt_index = torch.zeros(1, anchors, dtype=torch.long)
    boxes = torch.tensor(box).expand(1, anchors, 4).clone()
    scores = torch.ones(1, anchors, 1)
    return Assignment(fg, gt_index, boxes, scores), torch.zeros(1, 1, dtype=torch.long)


def test_input_resolution_equals_proto_resolution_on_block_constant_data() -> None:
    """Prototypes constant in space and a GT made of whole 4×4 blocks: the upsampled logits
    equal the grid's, every block holds 16 target pixels and the box area grows 16×, so the
    two resolutions give the same BCE (and the same Dice)."""
    torch.manual_seed(0)
    proto = torch.randn(1, 3, 1, 1).expand(1, 3, 4, 4).contiguous()
    coeffs = torch.randn(1, 3, 2)
    grid = torch.tensor([[[0, 1, 1, 0], [0, 1, 1, 0], [0, 0, 1, 0], [0, 0, 0, 0]]]).float()
    full = grid.repeat_interleave(4, 1).repeat_interleave(4, 2)  # [1, 16, 16]
    assigned, rows = _one_instance([4.0, 0.0, 12.0, 12.0], anchors=2)
    a = InstanceMaskLoss(MaskLossSpec("proto"))(proto, coeffs, assigned, rows, grid, (16, 16))
    b = InstanceMaskLoss(MaskLossSpec("input"))(proto, coeffs, assigned, rows, full, (16, 16))
    assert torch.allclose(a, b, rtol=1e-5)


def test_proto_mode_shrinks_full_masks_to_the_grid() -> None:
    """Given full-resolution masks, the proto mode takes them to the grid (nearest) first."""
    torch.manual_seed(1)
    proto, coeffs = torch.randn(1, 2, 4, 4), torch.randn(1, 2, 1)
    full = (torch.rand(1, 16, 16) > 0.5).float()
    assigned, rows = _one_instance([0.0, 0.0, 16.0, 16.0])
    loss = InstanceMaskLoss(MaskLossSpec("proto"))
    nearest = torch.nn.functional.interpolate(full[None], (4, 4), mode="nearest")[0]
    a = loss(proto, coeffs, assigned, rows, full, (16, 16))
    assert torch.allclose(a, loss(proto, coeffs, assigned, rows, nearest, (16, 16)))


def test_dice_term_by_hand() -> None:
    """Logits 0 on a 2×2 box fully covered by the GT: σ = 0.5, BCE ln 2 per pixel, Dice
    1 − (2·0.5·4 + 1)/(0.5·4 + 4 + 1) = 1 − 5/7."""
    proto, coeffs = torch.zeros(1, 1, 2, 2), torch.ones(1, 1, 1)
    gt = torch.ones(1, 2, 2)
    assigned, rows = _one_instance([0.0, 0.0, 2.0, 2.0])
    loss = InstanceMaskLoss(MaskLossSpec("input", dice=2.0))
    value = loss(proto, coeffs, assigned, rows, gt, (2, 2)).item()
    assert value == pytest.approx(math.log(2) + 2.0 * (1 - 5 / 7), rel=1e-6)


def test_thin_parts_are_the_limbs() -> None:
    """A 10×10 body survives a 5×5 opening; a 2 px wide, 12 px long arm does not."""
    m = torch.zeros(1, 32, 32)
    m[0, 4:14, 4:14] = 1.0
    m[0, 8:10, 14:26] = 1.0
    thin = thin_parts(m)
    assert thin.sum().item() == 24
    assert thin[0, 8:10, 14:26].sum().item() == 24


def test_thin_weight_adds_to_the_bce_on_thin_pixels_only() -> None:
    proto, coeffs = torch.zeros(1, 1, 16, 16), torch.ones(1, 1, 1)
    gt = torch.zeros(1, 16, 16)
    gt[0, 2:12, 2:12] = 1.0
    gt[0, 6:7, 12:15] = 1.0  # a 1 px wide, 3 px long arm
    assigned, rows = _one_instance([2.0, 2.0, 15.0, 12.0])
    plain = InstanceMaskLoss(MaskLossSpec("input"))(proto, coeffs, assigned, rows, gt, (16, 16))
    weighted = InstanceMaskLoss(MaskLossSpec("input", thin=3.0))
    value = weighted(proto, coeffs, assigned, rows, gt, (16, 16))
    area = 13 * 10
    assert (value - plain).item() == pytest.approx(3.0 * 3 * math.log(2) / area, rel=1e-5)


def test_full_resolution_supervision_learns_a_limb_the_grid_loses() -> None:
    """A 1 px wide vertical limb covers 1 of every 4×4 block's 4 columns: the block rule
    (≥ half) erases it from the stride-4 target, so fitting the prototypes there learns
    nothing of it, while the input-resolution loss recovers it after upsampling."""
    from slimseg.data.collate import downsample_masks

    gt_full = torch.zeros(1, 32, 32)
    gt_full[0, 4:28, 6:14] = 1.0  # body
    gt_full[0, 4:28, 21] = 1.0  # limb, 1 px
    grid = torch.from_numpy(downsample_masks(gt_full.numpy().astype("uint8"), 4)).float()
    assert grid[0, :, 5].sum() == 0  # the limb's block column is empty
    assigned, rows = _one_instance([4.0, 4.0, 24.0, 28.0])
    recalls = {}
    for mode, target in (("proto", grid), ("input", gt_full)):
        torch.manual_seed(0)
        proto = torch.zeros(1, 1, 8, 8, requires_grad=True)
        coeffs = torch.ones(1, 1, 1)
        opt = torch.optim.Adam([proto], lr=0.1)
        loss = InstanceMaskLoss(MaskLossSpec(mode))
        for _ in range(300):
            opt.zero_grad()
            loss(proto, coeffs, assigned, rows, target, (32, 32)).backward()
            opt.step()
        up = torch.nn.functional.interpolate(proto.detach(), (32, 32), mode="bilinear")
        mask = up[0, 0] > 0
        recalls[mode] = mask[4:28, 21].float().mean().item()
    assert recalls["proto"] == 0.0
    assert recalls["input"] > 0.9


def test_target_ratio_follows_the_spec() -> None:
    import dataclasses

    spec = get_spec("yolov8n-seg")
    assert target_mask_ratio(spec) == 4
    hr = dataclasses.replace(spec, head=dataclasses.replace(spec.head, proto_stride=2))
    assert target_mask_ratio(hr) == 2
    full = dataclasses.replace(
        spec, head=dataclasses.replace(hr.head, mask_loss=MaskLossSpec("input"))
    )
    assert target_mask_ratio(full) == 1


def test_mask_loss_spec_errors_name_the_field() -> None:
    with pytest.raises(SpecError, match=r"mask_loss\.resolution"):
        MaskLossSpec("full")
    with pytest.raises(SpecError, match="dice"):
        MaskLossSpec(dice=-1.0)
