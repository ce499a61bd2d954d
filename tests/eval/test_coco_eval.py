"""COCO evaluation on a tiny hand-made ground truth with predictions of known quality."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

from slimseg.data.coco import CocoDataset
from slimseg.detections import FrameDetections
from slimseg.errors import SlimsegError
from slimseg.eval.coco_eval import CocoEvaluator, format_metrics_table

CAT_IDS = (5, 9, 12)  # contiguous 0 person, 1 chair, 2 dog (no ground truth)
NAMES = ("person", "chair", "dog")
IMAGES = {10: (80, 100), 11: (90, 120), 12: (48, 64)}  # id: (h, w)
# Recall points below/at 0.5 when half the objects of a class are found first: 51 of 101.
HALF = 51 / 101

# pycocotools.mask.decode (used by COCO.annToMask below) trips numpy 2's copy= check.
pytestmark = pytest.mark.filterwarnings("ignore:__array__ implementation:DeprecationWarning")


def _block_rle(h: int, w: int, x0: int, y0: int, x1: int, y1: int) -> dict:
    m = np.zeros((h, w), np.uint8)
    m[y0:y1, x0:x1] = 1
    rle = mask_utils.encode(np.asfortranarray(m))
    rle["counts"] = rle["counts"].decode("ascii")
    return rle


def gt_dict() -> dict:
    """3 images, 4 instances of 2 classes: a rectangle polygon, a box-only instance (no
    segmentation), a triangle polygon, and an RLE without ``area``/``iscrowd``."""
    return {
        "images": [
            {"id": i, "file_name": f"{i}.jpg", "height": h, "width": w}
            for i, (h, w) in IMAGES.items()
        ],
        "categories": [{"id": c, "name": n} for c, n in zip(CAT_IDS, NAMES, strict=True)],
        "annotations": [
            {
                "id": 1,
                "image_id": 10,
                "category_id": 5,
                "bbox": [10, 10, 40, 20],
                "area": 800,
                "iscrowd": 0,
                "segmentation": [[10, 10, 50, 10, 50, 30, 10, 30]],
            },
            {
                "id": 2,
                "image_id": 10,
                "category_id": 9,
                "bbox": [60, 40, 30, 30],
                "area": 900,
                "iscrowd": 0,
            },
            {
                "id": 3,
                "image_id": 11,
                "category_id": 5,
                "bbox": [20, 10, 60, 50],
                "area": 1500,
                "iscrowd": 0,
                "segmentation": [[20, 10, 80, 10, 50, 60]],
            },
            {
                "id": 4,
                "image_id": 11,
                "category_id": 9,
                "bbox": [20, 50, 40, 20],
                "segmentation": _block_rle(90, 120, 20, 50, 60, 70),
            },
        ],
    }


@pytest.fixture
def gt_path(tmp_path: Path) -> Path:
    path = tmp_path / "gt.json"
    path.write_text(json.dumps(gt_dict()))
    return path


def predictions(
    ev: CocoEvaluator,
    spec: dict[int, float],
    shift: dict[int, int] | None = None,
    masks: bool = True,
    extra: dict[int, list[tuple[int, list[float], float]]] | None = None,
) -> dict[int, FrameDetections]:
    """Ground truth turned into detections: ``spec`` {ann id: score}; ``shift`` {ann id: dx}
    moves box and mask ``dx`` pixels right; ``extra`` {image id: [(class, xyxy, score)]}."""
    shift = shift or {}
    out = {}
    for img_id, (h, w) in IMAGES.items():
        boxes, scores, classes, ms = [], [], [], []
        for aid in ev.gt.getAnnIds(imgIds=[img_id]):
            if aid not in spec:
                continue
            ann = ev.gt.anns[aid]
            x, y, bw, bh = ann["bbox"]
            dx = shift.get(aid, 0)
            boxes.append([x + dx, y, x + dx + bw, y + bh])
            scores.append(spec[aid])
            classes.append(CAT_IDS.index(ann["category_id"]))
            ms.append(np.roll(ev.gt.annToMask(ann).astype(bool), dx, axis=1))
        for cls, box, score in (extra or {}).get(img_id, []):
            boxes.append(box)
            scores.append(score)
            classes.append(cls)
            ms.append(np.zeros((h, w), bool))
        out[img_id] = FrameDetections(
            boxes=np.asarray(boxes, np.float32).reshape(-1, 4),
            scores=np.asarray(scores, np.float32),
            classes=np.asarray(classes, np.int64),
            image_hw=(h, w),
            masks=np.asarray(ms, bool).reshape(-1, h, w) if masks else None,
        )
    return out


def run(ev: CocoEvaluator, preds: dict[int, FrameDetections], ids: list[int] | None = None):
    ids = list(IMAGES) if ids is None else ids
    ev.update(ids, [preds[i] for i in ids])
    return ev.summarize()


def per_class(result: dict, key: str) -> list:
    return [e[key] for e in result["per_class"]]


def test_ground_truth_as_predictions_scores_one(gt_path: Path) -> None:
    ev = CocoEvaluator(gt_path, CAT_IDS)
    res = run(ev, predictions(ev, {1: 1.0, 2: 1.0, 3: 1.0, 4: 1.0}))
    assert set(res) == {"box", "mask", "per_class"}
    for kind in ("box", "mask"):
        assert res[kind]["map50_95"] == pytest.approx(1.0, abs=1e-6)
        assert res[kind]["map50"] == pytest.approx(1.0, abs=1e-6)
    assert per_class(res, "class") == list(NAMES)
    assert per_class(res, "instances") == [2, 2, 0]
    for key in ("box_map50_95", "box_map50", "mask_map50_95", "mask_map50"):
        assert per_class(res, key)[:2] == pytest.approx([1.0, 1.0], abs=1e-6)
        assert per_class(res, key)[2] is None  # dog: no ground truth
    assert ev.coco_stats["segm"][0] == pytest.approx(1.0)


def test_shifted_predictions_give_the_computed_map(gt_path: Path) -> None:
    """Person: the rectangle is shifted by half its width (IoU 1/3 < 0.5: a false positive at
    every threshold) and scored below the exact triangle → precision 1 up to recall 0.5, AP
    51/101 at every IoU. Chair: the RLE block (40 px wide) is shifted 8 px (IoU 32/48 = 2/3:
    a hit for thresholds 0.50-0.65 only) and scored below the exact box instance → AP 1 at 4
    thresholds, 51/101 at the 6 others. A dog detection (no dog ground truth) changes nothing."""
    ev = CocoEvaluator(gt_path, CAT_IDS, names=NAMES)
    preds = predictions(
        ev,
        {1: 0.9, 2: 1.0, 3: 1.0, 4: 0.8},
        shift={1: 20, 4: 8},
        extra={12: [(2, [5.0, 5.0, 20.0, 20.0], 0.5)]},
    )
    res = run(ev, preds)
    person, chair = HALF, (4 * 1.0 + 6 * HALF) / 10
    for kind in ("box", "mask"):
        assert res[kind]["map50_95"] == pytest.approx((person + chair) / 2, abs=1e-6)
        assert res[kind]["map50"] == pytest.approx((HALF + 1.0) / 2, abs=1e-6)
        assert per_class(res, f"{kind}_map50_95")[:2] == pytest.approx([person, chair], abs=1e-6)
        assert per_class(res, f"{kind}_map50")[:2] == pytest.approx([HALF, 1.0], abs=1e-6)
        assert per_class(res, f"{kind}_map50_95")[2] is None


def test_no_predictions_give_zero(gt_path: Path) -> None:
    ev = CocoEvaluator(gt_path, CAT_IDS)
    res = run(ev, {i: FrameDetections.empty(hw, with_masks=True) for i, hw in IMAGES.items()})
    assert res["box"] == {"map50_95": 0.0, "map50": 0.0}
    assert res["mask"] == {"map50_95": 0.0, "map50": 0.0}
    assert per_class(res, "box_map50_95") == [0.0, 0.0, None]
    assert per_class(res, "mask_map50") == [0.0, 0.0, None]
    # Nothing evaluated at all.
    empty = CocoEvaluator(gt_path, CAT_IDS).summarize()
    assert empty["box"]["map50_95"] == 0.0 and per_class(empty, "box_map50") == [None] * 3


def test_partial_run_restricts_to_seen_images(gt_path: Path) -> None:
    ev = CocoEvaluator(COCO(str(gt_path)), CAT_IDS)  # a COCO object works too
    res = run(ev, predictions(ev, {1: 1.0, 2: 1.0}), ids=[10])
    assert res["box"]["map50_95"] == pytest.approx(1.0) and res["mask"]["map50"] == pytest.approx(1)
    assert per_class(res, "instances") == [1, 1, 0]
    # Image 11's objects, never predicted, would halve the recall if image 11 were seen.
    ev.update([11], [FrameDetections.empty(IMAGES[11], with_masks=True)])
    assert ev.summarize()["box"]["map50"] == pytest.approx(HALF)


def test_detect_only_and_table(gt_path: Path) -> None:
    ev = CocoEvaluator(gt_path, CAT_IDS, iou_types=("bbox",))
    preds = predictions(ev, {1: 0.9, 2: 1.0, 3: 1.0, 4: 0.8}, shift={1: 20}, masks=False)
    res = run(ev, preds)
    assert res["mask"] is None
    assert res["box"]["map50"] == pytest.approx((HALF + 1) / 2, abs=1e-6)
    assert per_class(res, "mask_map50_95") == [None] * 3
    table = format_metrics_table(res, NAMES)
    lines = table.splitlines()
    assert lines[0].split() == ["class", "instances", "box", "mAP50-95", "box", "mAP50"]
    assert lines[2].split()[:2] == ["all", "4"] and lines[3].split()[0] == "person"
    assert lines[5].split() == ["dog", "0", "-", "-"]

    seg = CocoEvaluator(gt_path, CAT_IDS)
    seg_table = format_metrics_table(run(seg, predictions(seg, {1: 1.0, 2: 1.0, 3: 1.0, 4: 1.0})))
    assert "mask mAP50-95" in seg_table
    assert seg_table.splitlines()[2].split() == ["all", "4", *["1.000"] * 4]


def test_from_dataset_uses_its_mapping(gt_path: Path, tmp_path: Path) -> None:
    (tmp_path / "images").mkdir()
    ds = CocoDataset(tmp_path / "images", gt_path, names=["chair", "person"])
    ev = CocoEvaluator.from_dataset(ds)
    assert ev.cat_ids == (9, 5) and ev.names == ("chair", "person")
    # Class 0 is now chair: exact chairs only, persons missed → chair 1, person 0.
    det = FrameDetections(
        np.asarray([[60, 40, 90, 70]], np.float32),
        np.ones(1, np.float32),
        np.zeros(1, np.int64),
        IMAGES[10],
        masks=ev.gt.annToMask(ev.gt.anns[2])[None].astype(bool),
    )
    ev.update([10], [det])
    res = ev.summarize()
    assert per_class(res, "box_map50") == pytest.approx([1.0, 0.0])
    assert per_class(res, "mask_map50_95") == pytest.approx([1.0, 0.0])
    assert res["box"]["map50"] == pytest.approx(0.5)


def test_bad_inputs(gt_path: Path) -> None:
    ev = CocoEvaluator(gt_path, CAT_IDS)
    empty = FrameDetections.empty(IMAGES[10], with_masks=True)
    with pytest.raises(SlimsegError):
        ev.update([999], [empty])
    ev.update([10], [empty])
    with pytest.raises(ValueError, match="twice"):
        ev.update([10], [empty])
    no_masks = FrameDetections(
        np.zeros((1, 4), np.float32), np.ones(1, np.float32), np.zeros(1, np.int64), IMAGES[11]
    )
    with pytest.raises(ValueError, match="masks"):
        ev.update([11], [no_masks])
    with pytest.raises(SlimsegError):
        CocoEvaluator(gt_path, (5, 7))
    with pytest.raises(ValueError):
        CocoEvaluator(gt_path, CAT_IDS, iou_types=("segm",))


def test_written_results_json_rescores_the_same(gt_path: Path, tmp_path: Path) -> None:
    ev = CocoEvaluator(gt_path, CAT_IDS)
    res = run(ev, predictions(ev, {1: 0.9, 2: 0.8, 3: 0.7}, shift={2: 3}))
    written = json.loads(ev.write_results(tmp_path / "results.json").read_text())
    assert len(written) == 3 and {"bbox", "segmentation", "score"} <= set(written[0])
    coco_gt = ev.gt
    for iou_type, key in (("bbox", "box"), ("segm", "mask")):
        dt = coco_gt.loadRes([dict(r) for r in written])
        e = COCOeval(coco_gt, dt, iou_type)
        e.params.imgIds = sorted(IMAGES)
        e.params.catIds = sorted(CAT_IDS)
        with contextlib.redirect_stdout(io.StringIO()):
            e.evaluate()
            e.accumulate()
            e.summarize()
        assert e.stats[0] == pytest.approx(res[key]["map50_95"], abs=1e-9)
