"""Box functions on hand-computed cases."""

from __future__ import annotations

import math

import pytest
import torch

from slimseg.ops.boxes import (
    box_ciou_pairwise,
    box_iou_pairwise,
    box_to_distances,
    distances_to_box,
    xywh_to_xyxy,
    xyxy_to_xywh,
)


def test_format_round_trip() -> None:
    b = torch.tensor([[10.0, 20.0, 4.0, 6.0]])
    assert xywh_to_xyxy(b).tolist() == [[8.0, 17.0, 12.0, 23.0]]
    torch.testing.assert_close(xyxy_to_xywh(xywh_to_xyxy(b)), b)


def test_iou_hand_cases() -> None:
    a = torch.tensor([[0.0, 0.0, 2.0, 2.0], [0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 1.0, 1.0]])
    b = torch.tensor([[1.0, 0.0, 3.0, 2.0], [0.0, 0.0, 1.0, 1.0], [2.0, 2.0, 3.0, 3.0]])
    assert box_iou_pairwise(a, b).tolist() == pytest.approx([2 / 6, 1.0, 0.0], abs=1e-6)


def test_ciou_hand_case() -> None:
    # same shape (v = 0), shifted by 1 in x: IoU = 1/3, enclosing diagonal² = 3² + 2² = 13
    a = torch.tensor([0.0, 0.0, 2.0, 2.0])
    b = torch.tensor([1.0, 0.0, 3.0, 2.0])
    assert box_ciou_pairwise(a, b).item() == pytest.approx(1 / 3 - 1 / 13, abs=1e-6)
    # same centre, different aspect: IoU = 2/4... v term only
    c = torch.tensor([0.0, 0.0, 4.0, 2.0])
    d = torch.tensor([1.0, 0.0, 3.0, 2.0])
    iou = 0.5
    v = 4 / math.pi**2 * (math.atan(1.0) - math.atan(2.0)) ** 2
    assert box_ciou_pairwise(c, d).item() == pytest.approx(iou - v * v / (v - iou + 1), abs=1e-5)
    assert box_ciou_pairwise(a, a).item() == pytest.approx(1.0, abs=1e-6)


def test_ciou_gradient_is_finite() -> None:
    a = torch.tensor([[0.0, 0.0, 2.0, 3.0]], requires_grad=True)
    b = torch.tensor([[5.0, 5.0, 6.0, 9.0]])
    (1 - box_ciou_pairwise(a, b)).sum().backward()
    assert torch.isfinite(a.grad).all() and a.grad.abs().sum() > 0


def test_distances_round_trip_and_clamp() -> None:
    pts = torch.tensor([[5.0, 5.0]])
    box = torch.tensor([[2.0, 1.0, 9.0, 30.0]])
    d = box_to_distances(pts, box, limit=14.99)
    assert d.tolist()[0] == pytest.approx([3.0, 4.0, 4.0, 14.99])
    unclamped = box_to_distances(pts, box, limit=100.0)
    torch.testing.assert_close(distances_to_box(pts, unclamped), box)
