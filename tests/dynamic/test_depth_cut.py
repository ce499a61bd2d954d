"""Masks that stay on their object: pixels well behind the object's depth are cut."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from conftest import frame_objects

from slimseg.dynamic.depth_cut import cut_behind, reference_depths
from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.masking_settings import PAPERS
from slimseg.dynamic.pipeline import FrameRules, process_frame

HW = (60, 80)


def _scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A person at 2 m whose mask spills onto the wall at 4 m; a hole without depth; an arm
    reaching out at 1.5 m."""
    depth = np.full(HW, 4.0, np.float32)
    depth[10:50, 10:30] = 2.0  # the person
    depth[20:25, 30:36] = 1.5  # the arm, in front
    depth[40:45, 12:16] = 0.0  # no depth
    mask = np.zeros(HW, bool)
    mask[10:50, 10:40] = True  # spills 4-10 px onto the wall on the right
    return mask[None], depth, np.array([[10, 10, 40, 50]], np.float32)


def test_cut_keeps_the_object_the_arm_and_pixels_without_depth() -> None:
    masks, depth, boxes = _scene()
    ref = reference_depths(masks, boxes, depth)
    assert ref.tolist() == [2.0]
    cut = cut_behind(masks.copy(), boxes, depth, ref, 0.5)[0]
    assert cut[10:50, 10:30].all()  # the person, its depthless hole included
    assert cut[20:25, 30:36].all()  # the arm in front
    assert not cut[30:50, 30:40].any() and not cut[10:20, 36:40].any()  # the wall
    assert masks[0, 30, 35]  # the input is not changed


def test_a_mask_without_depth_is_kept_whole() -> None:
    masks, depth, boxes = _scene()
    depth[:] = np.nan
    ref = reference_depths(masks, boxes, depth)
    assert np.isnan(ref[0])
    np.testing.assert_array_equal(cut_behind(masks.copy(), boxes, depth, ref, 0.5), masks)


def test_the_pipeline_cuts_seg_masks_and_eq4_boxes_and_only_when_asked() -> None:
    masks, depth, boxes = _scene()
    ys, xs = np.mgrid[2:58:4, 2:78:4]
    kps = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float32)
    on_wall = (kps[:, 0] >= 31) & (kps[:, 0] < 40) & (kps[:, 1] >= 30) & (kps[:, 1] < 50)
    inputs = FrameInputs(kps, frame_objects(boxes, np.zeros(1, np.int64), masks, HW), depth_m=depth)
    mob = np.array([1.0], np.float32)
    plain = process_frame(
        inputs=inputs, settings=FrameRules(mob, "seg", PAPERS.with_values(min_static=10))
    )
    assert plain.dynamic[on_wall].all()
    rules = FrameRules(mob, "seg", PAPERS.with_values(min_static=10, cut_behind_m=0.5))
    cut = process_frame(inputs=inputs, settings=rules)
    assert not cut.dynamic[on_wall].any() and cut.dynamic.sum() < plain.dynamic.sum()
    # Eq. 4: a mask too thin for its box becomes the box, which is cut by depth too
    thin = np.zeros_like(masks)
    thin[0, 20:24, 12:20] = True
    fused = process_frame(
        inputs=FrameInputs(
            kps, frame_objects(boxes, np.zeros(1, np.int64), thin, HW), depth_m=depth
        ),
        settings=FrameRules(
            mob, "fusion", PAPERS.with_values(min_static=10, cut_behind_m=0.5, frame_ratio=0.0)
        ),
    )
    assert fused.used_seg == [False]
    assert fused.mask[30, 20] == 255 and fused.mask[40, 35] == 0  # person in, wall out


def test_a_coarse_mask_mostly_on_the_wall_is_cut_to_the_person_in_front() -> None:
    """The failure of a median reference: a mask holding more wall (4 m) than person (2 m) put
    its object on the wall, and the box cut to that layer kept the wall whole."""
    depth = np.full(HW, 4.0, np.float32)
    depth[10:50, 20:30] = 2.0  # the person: 400 px of the mask's 1200
    mask = np.zeros(HW, bool)
    mask[10:50, 10:40] = True
    boxes = np.array([[10, 10, 40, 50]], np.float32)
    assert np.median(depth[mask]) == 4.0
    ref = reference_depths(mask[None], boxes, depth)
    assert ref.tolist() == [2.0]
    cut = cut_behind(mask[None].copy(), boxes, depth, ref, 0.5)[0]
    assert cut[10:50, 20:30].all() and cut.sum() == 400


def test_the_reference_is_the_sorted_sample_at_the_quantile_index() -> None:
    """The order statistic the C++ consumer mirrors: sorted valid samples, index
    int(REFERENCE_QUANTILE * (S - 1)), no interpolation."""
    from slimseg.dynamic.depth_cut import REFERENCE_QUANTILE

    rng = np.random.default_rng(3)
    depth = rng.uniform(0.5, 6.0, HW).astype(np.float32)
    depth[rng.random(HW) < 0.2] = 0.0  # no depth: not sampled
    mask = np.zeros(HW, bool)
    mask[5:55, 7:70] = True
    boxes = np.array([[7, 5, 70, 55]], np.float32)
    area = int(mask.sum())
    step = max(1, int(np.sqrt(area / 400)))
    d = depth[5:55:step, 7:70:step]
    d = np.sort(d[d > 0])
    expected = d[int(REFERENCE_QUANTILE * (len(d) - 1))]
    assert reference_depths(mask[None], boxes, depth)[0] == expected


def test_without_depth_eq4_replaces_only_thin_masks() -> None:
    """RGB-only: a box nothing can cut is the room behind the object, so with the depth cut
    asked for and no depth (for the frame, or under one object's mask) Eq. 4 falls back to the
    papers' t_o: a seg mask covering 30 % of its box stays, one covering 10 % becomes the box."""
    hw = (60, 80)
    boxes = np.array([[0, 0, 40, 40], [40, 0, 80, 40]], np.float32)
    masks = np.zeros((2, *hw), bool)
    masks[0, 0:40, 0:12] = True  # 30 % of its box
    masks[1, 0:40, 40:44] = True  # 10 %
    kps = np.array([[20, 20], [60, 20], [5, 5], [42, 5]], np.float32)
    mob = np.array([1.0], np.float32)
    inputs = FrameInputs(kps, frame_objects(boxes, np.zeros(2, np.int64), masks, hw))
    rules = FrameRules(
        mob, "fusion", PAPERS.with_values(min_static=0, frame_ratio=0.0, t_o=1.0, cut_behind_m=0.5)
    )
    out = process_frame(inputs=inputs, settings=rules)
    assert out.used_seg == [True, False]
    assert out.dynamic.tolist() == [False, True, True, True]
    # the cut switched off: t_o 1 is asked for as it is, both masks become boxes
    whole = process_frame(
        inputs=inputs, settings=replace(rules, masking=rules.masking.with_values(cut_behind_m=0.0))
    )
    assert whole.used_seg == [False, False] and whole.dynamic.all()
    # depth for the frame but none under the first mask: that object alone falls back
    depth = np.full(hw, 3.0, np.float32)
    depth[0:40, 0:40] = 0.0
    per_object = process_frame(inputs=replace(inputs, depth_m=depth), settings=rules)
    assert per_object.used_seg == [True, False]
