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


def test_one_box_to_pixel_rule_everywhere() -> None:
    """The scalar rule, the torch mask-crop span and Eq. 4's numpy box masks agree, ties
    (x.5) included: a pixel is in a box when its centre is."""
    import numpy as np

    from slimseg.dynamic.seg_box import box_masks
    from slimseg.ops.boxes import box_pixel_bounds
    from slimseg.ops.masks import _pixel_span

    h, w = 23, 31
    rng = np.random.default_rng(0)
    boxes = rng.uniform(-3, 34, (200, 4)).round(1)
    boxes[:50] = np.floor(boxes[:50]) + 0.5  # exact ties
    boxes[:, 2:] = np.maximum(boxes[:, 2:], boxes[:, :2])
    filled = box_masks(boxes, (h, w))
    t = torch.from_numpy(boxes)
    c_first, c_count = _pixel_span(t[:, 0], t[:, 2], w)
    r_first, r_count = _pixel_span(t[:, 1], t[:, 3], h)
    for i, box in enumerate(boxes):
        r0, r1, c0, c1 = box_pixel_bounds(box, h, w)
        ref = np.zeros((h, w), bool)
        ref[r0:r1, c0:c1] = True
        assert np.array_equal(ref, filled[i]), box
        if r1 > r0 and c1 > c0:
            assert (c0, c1 - c0, r0, r1 - r0) == (
                int(c_first[i]),
                int(c_count[i]),
                int(r_first[i]),
                int(r_count[i]),
            ), box
    assert box_pixel_bounds((2.5, 0.0, 3.5, 1.0), h, w) == (0, 1, 2, 3)  # centre 2.5 is in
