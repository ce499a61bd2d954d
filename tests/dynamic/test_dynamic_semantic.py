"""Semantic class maps become per-component instances for the masking logic."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.pipeline import FrameRules, process_frame
from slimseg.dynamic.semantic import class_map_to_instances, objects_of


def test_components_per_class_with_boxes() -> None:
    cmap = np.zeros((40, 60), np.uint8)
    cmap[5:15, 5:20] = 1  # class 0, two separate blobs
    cmap[25:35, 5:10] = 1
    cmap[10:30, 40:50] = 3  # class 2
    cmap[0:2, 58:60] = 3  # 4 px of label noise
    boxes, classes, masks = class_map_to_instances(cmap, min_area=8)
    order = np.lexsort((boxes[:, 1], classes))
    boxes, classes, masks = boxes[order], classes[order], masks[order]
    assert classes.tolist() == [0, 0, 2]
    assert boxes.tolist() == [[5, 5, 20, 15], [5, 25, 10, 35], [40, 10, 50, 30]]
    assert [int(m.sum()) for m in masks] == [150, 50, 200]
    assert masks.shape == (3, 40, 60) and masks.dtype == bool


def test_empty_map_and_instance_passthrough() -> None:
    boxes, classes, masks = class_map_to_instances(np.zeros((8, 8), np.uint8))
    assert boxes.shape == (0, 4) and classes.shape == (0,) and masks.shape == (0, 8, 8)
    inst = SimpleNamespace(boxes=np.ones((1, 4)), scores=np.full(1, 0.3), classes=np.zeros(1),
                           masks=None, class_map=None)  # fmt: skip
    objects = objects_of(inst, (8, 8))
    assert objects.masks is None and objects.boxes.tolist() == [[1, 1, 1, 1]]
    assert objects.scores.tolist() == pytest.approx([0.3]) and objects.classes.dtype == np.int64


def test_semantic_person_points_become_dynamic() -> None:
    """A person region (class 0, mobility 1.0) and a chair region (class 1, 0.25): only the
    points on the person are dynamic in seg mode."""
    cmap = np.zeros((100, 100), np.uint8)
    cmap[10:60, 10:40] = 1
    cmap[50:90, 60:95] = 2
    objects = objects_of(SimpleNamespace(class_map=cmap), (100, 100))
    assert objects.scores.tolist() == [1.0, 1.0]  # a semantic map's components score 1
    rng = np.random.default_rng(0)
    kps = rng.uniform(0, 100, (400, 2)).astype(np.float32)
    result = process_frame(
        inputs=FrameInputs(kps, objects),
        settings=FrameRules(np.array([1.0, 0.25]), "seg"),
    )
    x, y = (np.clip(np.round(kps[:, i]).astype(int), 0, 99) for i in (0, 1))  # as the logic
    on_person = cmap[y, x] == 1
    assert np.array_equal(result.dynamic, on_person)
