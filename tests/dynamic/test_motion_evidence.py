"""Motion evidence weighs on mobility priors (odds form): static dogs give their keypoints back,
people stay masked, a pushed chair joins the mask; undecided objects keep their prior."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import frame_objects
from test_epipolar import H, W, _on, _pair

from slimseg.dynamic.epipolar import PreviousFrame
from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.masking_settings import PAPERS, SLIMSEG, SettingsError
from slimseg.dynamic.motion_evidence import weigh_motion
from slimseg.dynamic.pipeline import FrameRules, process_frame


def test_odds_by_hand() -> None:
    mob = np.array([0.75, 0.75, 0.25, 1.0, 0.0, 0.5], np.float32)
    out = weigh_motion(mob, [0, 1, 2, 3, 4, 5], np.array([1, 1, 1, 1, 1, 0], bool),
                       np.array([0, 1, 1, 0, 1, 1], bool), odds=10.0)  # fmt: skip
    # 0.75 = odds 3; static: 3 / 10 = 0.3 -> 0.3 / 1.3; moving: 30 -> 30 / 31
    np.testing.assert_allclose(out, [0.3 / 1.3, 30 / 31, (10 / 3) / (13 / 3), 1.0, 0.0, 0.5],
                               rtol=1e-6)  # fmt: skip
    assert out[0] < SLIMSEG.m_th_start < out[2]  # the static dog leaves, the pushed chair joins
    assert mob[0] == 0.75  # a new array


@pytest.mark.parametrize("mode", ["seg", "fusion"])
def test_a_static_dog_is_given_back_a_person_is_not(mode: str) -> None:
    f0, f1, _, masks = _pair()
    boxes = np.array([[50, 50, 116, 140], [193, 57, 253, 147]], np.float32)
    seg = np.stack([masks["static"], masks["mover"]])
    on_static, on_mover = _on(seg[0], f1.keypoints), _on(seg[1], f1.keypoints)
    mob = np.array([1.0, 0.75], np.float32)  # class 0 person, class 1 dog

    def run(classes: list[int], odds: float, previous: bool = True):
        inputs = FrameInputs(f1.keypoints, frame_objects(boxes, classes, seg, (H, W)),
                             descriptors=f1.descriptors,
                             previous=PreviousFrame(f0) if previous else None)  # fmt: skip
        rules = FrameRules(
            mob, mode, PAPERS.with_values(min_static=10, frame_ratio=1.0, motion_odds=odds)
        )
        return process_frame(inputs=inputs, settings=rules)

    # the static object as a dog: its prior 0.75 falls to 0.23 and its keypoints go back
    dog = run([1, 1], 10.0)
    assert not dog.dynamic[on_static].any() and dog.dynamic[on_mover].all()
    assert not dog.mask[masks["static"]].any()
    # as a person (prior 1): no evidence moves it, unlike VTD-SLAM's epipolar modes
    person = run([0, 1], 10.0)
    assert person.dynamic[on_static].all() and person.dynamic[on_mover].all()
    # odds 1 (the papers preset) and the first frame (no previous): the prior as it is
    for off in (run([1, 1], 1.0), run([1, 1], 10.0, previous=False)):
        assert off.dynamic[on_static].all() and off.dynamic[on_mover].all()
    # odds too weak to move 0.75 under 0.25: kept
    assert run([1, 1], 2.0).dynamic[on_static].all()


def test_presets_and_range() -> None:
    assert PAPERS.motion_odds == 1.0 and SLIMSEG.motion_odds == 10.0
    with pytest.raises(SettingsError, match="motion_odds"):
        SLIMSEG.with_values(motion_odds=0.5)
