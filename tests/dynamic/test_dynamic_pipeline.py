"""One frame through every mode: a walking person (mobility 1) and a chair (0.25)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import frame_objects

from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.masking_settings import PAPERS
from slimseg.dynamic.modes import MODES, Mode
from slimseg.dynamic.pipeline import (
    FrameRules,
    apply_rules,
    orb_keypoints,
    process_frame,
)

HW = (60, 80)
MOBILITY = np.array([1.0, 0.25], np.float32)  # person, chair


def _frame() -> tuple[np.ndarray, ...]:
    person = np.zeros(HW, bool)
    person[10:50, 8:30] = True  # most of its box, as a walking person is
    chair = np.zeros(HW, bool)
    chair[30:50, 50:70] = True
    boxes = np.array([[5, 10, 35, 50], [50, 30, 70, 50]], np.float32)
    masks = np.stack([person, chair])
    ys, xs = np.mgrid[2:58:4, 2:78:4]
    keypoints = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float32)
    depth = np.full(HW, 4.0, np.float32)
    depth[person] = 2.0
    return keypoints, boxes, np.array([0, 1]), masks, depth


@pytest.mark.parametrize("mode", MODES)
def test_modes_on_a_person_and_a_chair(mode: str) -> None:
    kps, boxes, classes, masks, depth = _frame()
    r = process_frame(
        inputs=FrameInputs(kps, frame_objects(boxes, classes, masks, HW), depth_m=depth),
        settings=FrameRules(MOBILITY, mode, PAPERS.with_values(min_static=10)),
        rng=np.random.default_rng(0),
    )
    on_person = (kps[:, 0] >= 8) & (kps[:, 0] < 30) & (kps[:, 1] >= 10) & (kps[:, 1] < 50)
    in_person_box = (kps[:, 0] >= 5) & (kps[:, 0] < 35) & (kps[:, 1] >= 10) & (kps[:, 1] < 50)
    on_chair = (kps[:, 0] >= 50) & (kps[:, 1] >= 30) & (kps[:, 1] < 50) & (kps[:, 0] < 70)
    assert r.dynamic[on_person].all()  # the person's points are always dropped
    assert not r.dynamic[on_chair].any()  # the chair (mobility 0.25) never is
    if mode == "box":
        assert r.dynamic[in_person_box].all()  # the whole box, wall points included
    else:
        assert not r.dynamic[in_person_box & ~on_person].any()  # wall behind stays static
    assert r.mask.dtype == np.uint8 and set(np.unique(r.mask)) <= {0, 255}


def test_fusion_replaces_a_mask_too_thin_for_its_box() -> None:
    kps, boxes, classes, masks, _ = _frame()
    masks[0] = False
    masks[0, 10:12, 10:20] = True  # 20 px of a 1200-px box: s_o < 0.25
    r = process_frame(
        inputs=FrameInputs(kps, frame_objects(boxes, classes, masks, HW)),
        settings=FrameRules(MOBILITY, "fusion", PAPERS.with_values(min_static=10)),
    )
    assert r.dynamic_frame and r.used_seg == [False, True]


def test_orb_finds_corners() -> None:
    img = np.zeros((120, 160, 3), np.uint8)
    img[30:90, 40:120] = 255
    img[50:70, 60:100] = 0
    assert len(orb_keypoints(img, 200)) > 4


def test_rules_of_every_mode_on_one_decision_per_mode_equal_one_mode_at_a_time() -> None:
    """What the report does (each mode decides, then applies its rules on the same inputs)
    equals each mode's own :func:`process_frame`."""
    kps, boxes, classes, masks, depth = _frame()
    inputs = FrameInputs(kps, frame_objects(boxes, classes, masks, HW), depth_m=depth)
    settings = FrameRules(MOBILITY, masking=PAPERS.with_values(min_static=10))
    rng_a, rng_b = np.random.default_rng(0), np.random.default_rng(0)
    for mode in MODES:
        shared = apply_rules(inputs, settings.decide(inputs, Mode(mode)), settings,
                             mode=Mode(mode), rng=rng_a)  # fmt: skip
        alone = process_frame(
            inputs=inputs,
            settings=FrameRules(MOBILITY, mode, PAPERS.with_values(min_static=10)),
            rng=rng_b,
        )
        assert np.array_equal(shared.dynamic, alone.dynamic), mode
        assert np.array_equal(shared.mask, alone.mask) and shared.seconds > 0
    with pytest.raises(ValueError, match="mode 'segm'"):
        apply_rules(inputs, settings.decide(inputs), settings, mode="segm")
