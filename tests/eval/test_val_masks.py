"""Validation masks: window RLEs, the per-class COCO limit and pinned pycocotools numbers.

The pinned numbers were computed on these fixed predictions by the previous implementation
(dense full-frame masks for every detection, ``pycocotools.mask.encode``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from pycocotools import mask as mask_utils

from slimseg.detections import Detections, encode_rle
from slimseg.eval.coco_eval import CocoEvaluator
from slimseg.eval.postprocess import COCO_MAX_DETS, to_frame_detections, within_class_limit
from slimseg.ops.letterbox import letterbox_params
from slimseg.ops.rle import window_rles

FRAMES = ((96, 96), (64, 80))  # (h, w): no resize at 96 px input, and a letterboxed resize
IMGSZ = 96


def ground_truth() -> dict:
    rng = np.random.default_rng(7)
    images, anns = [], []
    for i, (h, w) in enumerate(FRAMES, 1):
        images.append({"id": i, "file_name": f"{i}.png", "height": h, "width": w})
        for j in range(6):
            x0, y0 = int(rng.integers(0, w - 20)), int(rng.integers(0, h - 20))
            bw, bh = int(rng.integers(8, w - x0)), int(rng.integers(8, h - y0))
            m = np.zeros((h, w), np.uint8, order="F")
            m[y0 : y0 + bh, x0 : x0 + bw] = 1
            rle = mask_utils.encode(m)
            rle["counts"] = rle["counts"].decode("ascii")
            anns.append(
                {
                    "id": len(anns) + 1,
                    "image_id": i,
                    "category_id": 1 + j % 2,
                    "iscrowd": 0,
                    "segmentation": rle,
                    "area": float(bw * bh),
                    "bbox": [x0, y0, bw, bh],
                }
            )
    cats = [{"id": 1, "name": "a"}, {"id": 2, "name": "b"}]
    return {"images": images, "annotations": anns, "categories": cats}


def predictions(gt: dict) -> list[tuple[Detections, torch.Tensor, dict]]:
    """Per image: 260 detections (150 of class 0, 110 of class 1, tied scores included)
    jittered around the ground-truth boxes, prototypes that make box-like noisy masks."""
    g = torch.Generator().manual_seed(11)
    out = []
    for img, (h, w) in zip(gt["images"], FRAMES, strict=True):
        p = letterbox_params(h, w, IMGSZ, IMGSZ)
        boxes = []
        for a in (a for a in gt["annotations"] if a["image_id"] == img["id"]):
            x, y, bw, bh = a["bbox"]
            boxes.append(
                [
                    x * p.scale + p.left,
                    y * p.scale + p.top,
                    (x + bw) * p.scale + p.left,
                    (y + bh) * p.scale + p.top,
                ]
            )
        base = torch.tensor(boxes).repeat(44, 1)[:260]
        xyxy = (base + torch.randn(260, 4, generator=g) * 6).clamp(-4, IMGSZ + 4)
        xyxy[:, 2:] = torch.maximum(xyxy[:, 2:], xyxy[:, :2] + 1)
        classes = torch.cat([torch.zeros(150), torch.ones(110)]).long()
        classes = classes[torch.randperm(260, generator=g)]
        scores = (torch.rand(260, generator=g) * 50).round() / 50  # ties
        order = scores.argsort(descending=True, stable=True)
        coeffs = torch.randn(260, 8, generator=g)
        coeffs[:, 0] = 4.0
        proto = torch.randn(8, IMGSZ // 4, IMGSZ // 4, generator=g) * 0.8
        proto[0] = 1.0
        dets = Detections(xyxy[order], scores[order], classes[order], coeffs[order])
        out.append((dets, proto, {"letterbox": p, "orig_shape": (h, w)}))
    return out


PINNED = {
    "bbox": [0.12911669674157975, 0.41741097186641724, 0.028539763128173357,
             0.15973611443123617, 0.14375, -1.0, 0.025, 0.29166666666666663, 0.55, 0.52, 0.7,
             -1.0],
    "segm": [0.13730306477827156, 0.4069220197453987, 0.059854740921628215,
             0.16764236192433, 0.14, -1.0, 0.025, 0.3, 0.5166666666666667,
             0.49000000000000005, 0.65, -1.0],
}  # fmt: skip


@pytest.mark.parametrize("mask_limit", [None, COCO_MAX_DETS])
def test_pycocotools_numbers_are_pinned(mask_limit: int | None) -> None:
    gt = ground_truth()
    ev = CocoEvaluator(gt, [1, 2])
    frames = [
        to_frame_detections(d, pr, m, rle=True, mask_limit=mask_limit)
        for d, pr, m in predictions(gt)
    ]
    skipped = sum(r is None for f in frames for r in f.rles)
    assert skipped == (0 if mask_limit is None else 2 * (150 - COCO_MAX_DETS + 110 - 100))
    ev.update([1, 2], frames)
    ev.summarize()
    for iou_type, expected in PINNED.items():
        np.testing.assert_allclose(ev.coco_stats[iou_type], expected, rtol=0, atol=1e-12)


def test_frame_rles_equal_the_dense_masks_encoded() -> None:
    for dets, proto, meta in predictions(ground_truth()):
        dense = to_frame_detections(dets, proto, meta).masks
        rles = to_frame_detections(dets, proto, meta, rle=True).rles
        assert rles == encode_rle(dense)


def test_class_limit_keeps_the_first_detections_of_each_class() -> None:
    classes = torch.tensor([2, 0, 2, 2, 0, 1, 2])
    keep = within_class_limit(classes, 2)
    assert keep.tolist() == [True, True, True, False, True, True, False]
    assert within_class_limit(classes, None).all()
    assert within_class_limit(torch.zeros(0, dtype=torch.long), 2).shape == (0,)


def test_window_rles_equal_pycocotools_on_the_full_frame() -> None:
    g = torch.Generator().manual_seed(0)
    h, w = 13, 9
    for trial in range(60):
        sy = int(torch.randint(1, h + 1, (1,), generator=g))
        sx = int(torch.randint(1, w + 1, (1,), generator=g))
        top = torch.randint(-2, h - sy + 3, (5,), generator=g)
        left = torch.randint(-2, w - sx + 3, (5,), generator=g)
        values = torch.rand(5, sy, sx, generator=g) < torch.rand(5, 1, 1, generator=g)
        if trial % 4 == 0:
            values[:] = True  # full columns: runs continue across columns
        values[1] = False if trial % 3 == 0 else values[1]
        rows = top[:, None] + torch.arange(sy)
        cols = left[:, None] + torch.arange(sx)
        values &= ((rows >= 0) & (rows < h))[:, :, None] & ((cols >= 0) & (cols < w))[:, None]
        dense = np.zeros((5, h, w), bool)
        for d, i, j in values.nonzero().tolist():
            dense[d, rows[d, i], cols[d, j]] = True
        assert window_rles(values, top, left, (h, w)) == encode_rle(dense)
    assert window_rles(torch.zeros(0, 2, 2, dtype=torch.bool), top[:0], left[:0], (h, w)) == []
