"""Where precision is lost: false dynamic keypoints charged to the static instance they lie on
(by class) or to the background, by hand."""

from __future__ import annotations

import numpy as np
import pytest

from slimseg.detections import Prediction
from slimseg.sequence.precision_loss import BACKGROUND, PrecisionLoss
from slimseg.sequence.recall_loss import FrameInstances


def _frame() -> FrameInstances:
    """Two instances on a 10x20 frame: a moving person (x 0-4) and a standing one (x 10-14)."""
    masks = np.zeros((2, 10, 20), bool)
    masks[0, :, 0:5] = masks[1, :, 10:15] = True
    boxes = np.array([[0, 0, 5, 10], [10, 0, 15, 10]], np.float32)
    pred = Prediction(boxes=boxes, scores=np.ones(2, np.float32), classes=np.zeros(2, np.int64),
                      names=["person", "person"], mobility=[1.0, 1.0], masks=masks,
                      image_hw=(10, 20))  # fmt: skip
    return FrameInstances(pred, np.array([True, False]), np.array([1, 2]))


def test_false_dynamic_keypoints_by_what_they_lie_on() -> None:
    kps = np.array([[1, 1], [2, 5], [11, 2], [12, 3], [13, 8], [18, 4], [7, 7]], np.float32)
    truth = np.array([True, True, False, False, False, False, False])
    dynamic = np.array([True, False, True, True, True, True, False])  # 4 false, 1 true
    loss = PrecisionLoss()
    loss.add(_frame(), kps, dynamic, truth)
    loss.add(_frame(), kps, truth, truth)  # a perfect frame adds nothing
    assert loss.false_dynamic == 4
    assert loss.on == {"person": 3, BACKGROUND: 1}
    s = loss.summary()
    assert s["person_pct"] == pytest.approx(75.0) and s[f"{BACKGROUND}_pct"] == pytest.approx(25)
    assert loss.describe() == (
        "4 false dynamic keypoints: 75.0 % on static person, 25.0 % on background"
    )
    assert PrecisionLoss().describe() == "no false dynamic keypoints"
