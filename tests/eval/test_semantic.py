"""Semantic targets, instance → class-map painting, mIoU / MPA and the semantic loss."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from slimseg.data.collate import make_collate
from slimseg.data.sample import Sample
from slimseg.data.semantic import (
    ignore_padding,
    instances_to_semantic,
    semantic_target,
)
from slimseg.eval.semantic_metrics import ConfusionMatrix, format_semantic_table, semantic_metrics
from slimseg.losses.semantic import SemanticLoss
from slimseg.ops.letterbox import letterbox_params
from slimseg.ops.semantic import IGNORE_INDEX


def _masks(h: int, w: int, *boxes: tuple[int, int, int, int]) -> np.ndarray:
    out = np.zeros((len(boxes), h, w), np.uint8)
    for i, (y0, y1, x0, x1) in enumerate(boxes):
        out[i, y0:y1, x0:x1] = 1
    return out


def test_semantic_target_paints_later_instances_over_earlier() -> None:
    masks = _masks(4, 6, (0, 2, 0, 3), (1, 3, 2, 5))  # overlap at rows 1, column 2
    got = semantic_target(masks, np.array([0, 4]))
    want = np.array(
        [
            [1, 1, 1, 0, 0, 0],
            [1, 1, 5, 5, 5, 0],
            [0, 0, 5, 5, 5, 0],
            [0, 0, 0, 0, 0, 0],
        ]
    )
    np.testing.assert_array_equal(got, want)
    assert got.dtype == np.int64
    assert semantic_target(np.zeros((0, 2, 3), np.uint8), np.zeros(0, np.int64)).sum() == 0


def test_instances_paint_by_ascending_confidence() -> None:
    masks = _masks(2, 2, (0, 2, 0, 2), (0, 1, 0, 2))
    high_first = instances_to_semantic(masks, np.array([1, 2]), np.array([0.9, 0.3]))
    np.testing.assert_array_equal(high_first, [[2, 2], [2, 2]])  # the 0.9 one wins everywhere
    low_first = instances_to_semantic(masks, np.array([1, 2]), np.array([0.3, 0.9]))
    np.testing.assert_array_equal(low_first, [[3, 3], [2, 2]])


def test_ignore_padding_and_collate_targets() -> None:
    p = letterbox_params(2, 4, 4)  # 2x4 frame in a 4x4 input: rows 0 and 3 are padding
    got = ignore_padding(np.ones((4, 4), np.int64), p)
    assert (got[[0, 3]] == IGNORE_INDEX).all() and (got[1:3] == 1).all()
    masks = _masks(4, 4, (1, 3, 0, 2))
    sample = Sample(
        image=np.zeros((4, 4, 3), np.uint8),
        boxes=np.array([[0, 1, 2, 3]], np.float32),
        classes=np.array([2]),
        masks=masks,
        meta={"letterbox": p, "orig_shape": (2, 4)},
    )
    batch = make_collate(mask_ratio=1, semantic=True)([sample])
    sem = batch["semantic"]
    assert sem.shape == (1, 4, 4) and sem.dtype == torch.int64
    assert (sem[0, 0] == IGNORE_INDEX).all() and sem[0, 1, 0] == 3 and sem[0, 1, 3] == 0


def test_metrics_on_a_hand_built_confusion() -> None:
    # GT:   0 0 1 1 2 2      pred: 0 1 1 1 2 0   (3 labels: background, a, b)
    gt = np.array([0, 0, 1, 1, 2, 2])
    pred = np.array([0, 1, 1, 1, 2, 0])
    cm = ConfusionMatrix(3)
    cm.update(pred, gt)
    np.testing.assert_array_equal(cm.matrix.numpy(), [[1, 1, 0], [0, 2, 0], [1, 0, 1]])
    r = cm.compute(["a", "b"])
    # IoU: bg 1/(2+2-1) = 1/3, a 2/(2+3-2) = 2/3, b 1/(2+1-1) = 1/2; PA: 1/2, 1, 1/2
    assert [c["iou"] for c in r["per_class"]] == pytest.approx([1 / 3, 2 / 3, 1 / 2])
    assert [c["pa"] for c in r["per_class"]] == pytest.approx([1 / 2, 1.0, 1 / 2])
    assert r["miou"] == pytest.approx((1 / 3 + 2 / 3 + 1 / 2) / 3)
    assert r["mpa"] == pytest.approx(2 / 3)
    assert r["miou_fg"] == pytest.approx((2 / 3 + 1 / 2) / 2)
    assert r["pixel_acc"] == pytest.approx(4 / 6)
    assert "mIoU 50.0 %" in format_semantic_table(r)


def test_absent_classes_and_ignored_pixels() -> None:
    # 4 labels: class 2 never appears (excluded); class 3 is predicted but absent from GT
    gt = np.array([0, 0, 1, 1, IGNORE_INDEX])
    pred = np.array([0, 3, 1, 1, 2])  # the ignored pixel's prediction does not count
    cm = ConfusionMatrix(4)
    cm.update(pred, gt)
    r = semantic_metrics(cm.matrix.numpy())
    ious = [c["iou"] for c in r["per_class"]]
    pas = [c["pa"] for c in r["per_class"]]
    assert ious[:2] == pytest.approx([0.5, 1.0]) and math.isnan(ious[2]) and ious[3] == 0.0
    assert pas[:2] == pytest.approx([0.5, 1.0]) and math.isnan(pas[2]) and math.isnan(pas[3])
    assert r["miou"] == pytest.approx(0.5)  # (0.5 + 1 + 0) / 3
    assert r["mpa"] == pytest.approx(0.75)  # (0.5 + 1) / 2
    assert r["pixels"] == 4


def test_confusion_rejects_out_of_range_ids() -> None:
    with pytest.raises(ValueError, match="out of range"):
        ConfusionMatrix(2).update(np.array([2]), np.array([0]))


def test_semantic_loss_is_low_for_right_logits_and_ignores_pixels() -> None:
    target = torch.tensor([[[0, 1], [2, IGNORE_INDEX]]])
    right = torch.nn.functional.one_hot(target.clamp(max=2), 3).permute(0, 3, 1, 2) * 20.0
    wrong = right.roll(1, dims=1)
    loss = SemanticLoss()
    good, terms = loss(right.float(), target)
    bad, _ = loss(wrong.float(), target)
    assert good < 0.01 and bad > 1.0 and set(terms) == {"ce", "dice"}
    # changing the ignored pixel's logits changes nothing
    other = right.clone().float()
    other[0, :, 1, 1] = torch.tensor([5.0, -3.0, 9.0])
    assert loss(other, target)[0] == pytest.approx(good.item())
