"""Eq. 1 adaptive threshold, Eq. 3 dynamic frame, Eq. 4 seg/box fusion on hand-built cases."""

from __future__ import annotations

import numpy as np
import pytest

from slimseg.dynamic.seg_box import box_masks, dilate, fuse_seg_box
from slimseg.dynamic.threshold import adaptive_threshold, is_dynamic_frame, keypoint_mobility


def _scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A person (mobility 1.0) left, a ball (0.75) right, a keyboard (0.25) bottom."""
    masks = np.zeros((3, 40, 60), bool)
    masks[0, 5:30, 5:20] = True
    masks[1, 5:15, 40:50] = True
    masks[2, 32:38, 20:40] = True
    return masks, np.array([1.0, 0.75, 0.25], np.float32), np.array([[10, 10], [45, 10], [30, 35]])


def test_keypoint_mobility_takes_the_mask_under_each_point() -> None:
    masks, mob, _ = _scene()
    pts = np.array([[10.0, 10.0], [45.0, 10.0], [30.0, 35.0], [55.0, 35.0]])
    assert keypoint_mobility(pts, masks, mob).tolist() == [1.0, 0.75, 0.25, 0.0]


def test_eq1_starts_at_025_and_raises_by_01() -> None:
    m = np.array([1.0] * 10 + [0.75] * 10 + [0.25] * 5 + [0.0] * 5)
    first = adaptive_threshold(m, min_static=10)
    assert first.m_th == 0.25 and first.static_count == 10  # 0.25 and 0.0 points stay
    raised = adaptive_threshold(m, min_static=15)  # needs the 0.75 points static too
    assert raised.m_th == pytest.approx(0.75) and raised.static_count == 20
    assert raised.dynamic[:10].all() and not raised.dynamic[10:].any()


def test_eq1_gives_up_past_one() -> None:
    result = adaptive_threshold(np.ones(20), min_static=5)
    assert result.m_th is None and not result.dynamic.any()


def test_eq3_dynamic_frame_ratio() -> None:
    m = np.array([1.0] * 3 + [0.25] * 97)
    assert is_dynamic_frame(m, ratio=0.02) and not is_dynamic_frame(m, ratio=0.05)
    assert not is_dynamic_frame(np.array([]))


def test_eq4_box_replaces_thin_seg_mask() -> None:
    boxes = np.array([[0, 0, 20, 20], [30, 0, 50, 20]], np.float32)
    seg = np.zeros((2, 30, 60), bool)
    seg[0, 0:20, 0:20] = True  # covers its whole box → kept
    seg[1, 0:4, 30:50] = True  # 20 % of its box → replaced by the box
    fused, used_seg = fuse_seg_box(seg, boxes)
    assert used_seg.tolist() == [True, False]
    assert fused[1].sum() == 400 and np.array_equal(fused[1], box_masks(boxes, (30, 60))[1])


def test_dilate_grows_by_radius() -> None:
    mask = np.zeros((21, 21), bool)
    mask[10, 10] = True
    grown = dilate(mask, 3)
    assert grown[10, 13] and grown[13, 10] and not grown[10, 14] and grown.sum() > 20


def test_crop_based_masking_equals_the_full_frame_rules() -> None:
    """Eq. 4, box mobility and mask dilation on each mask's crop give the very pixels of the
    full-frame formulas (the masking logic's cost follows the objects, not M frames)."""
    from slimseg.dynamic.seg_box import box_keypoint_mobility, dilate_masks

    rng = np.random.default_rng(3)
    hw = (60, 80)
    boxes = np.c_[rng.uniform(-10, 70, (12, 2)), np.zeros((12, 2))].astype(np.float32)
    boxes[:, 2:] = boxes[:, :2] + rng.uniform(0, 40, (12, 2))
    boxes[0] = [-5, -5, 90, 70]  # beyond every border
    boxes[1] = [10.5, 10.5, 10.5, 30]  # empty
    seg = box_masks(boxes, hw) & (rng.random((12, *hw)) < 0.4)
    seg[2] = False  # an empty mask
    full_box = box_masks(boxes, hw)
    area = full_box.sum((1, 2)).clip(min=1)
    used_ref = (seg & full_box).sum((1, 2)) / area > 0.25
    fused, used = fuse_seg_box(seg, boxes, 0.25)
    assert np.array_equal(used, used_ref)
    assert np.array_equal(fused, np.where(used_ref[:, None, None], seg, full_box))
    pts = rng.uniform(-3, 83, (200, 2))
    mob = rng.random(12).astype(np.float32)
    assert np.array_equal(
        box_keypoint_mobility(pts, boxes, hw, mob), keypoint_mobility(pts, full_box, mob)
    )
    for r in (1, 5):
        assert np.array_equal(dilate_masks(seg, r), np.stack([dilate(m, r) for m in seg]))
