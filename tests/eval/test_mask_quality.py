"""Mask quality: boundary bands, Boundary AP, Zhang–Suen skeletons, skeleton recall of people,
the mask-grid ceiling and ``slimseg val --mask-quality`` / ``--ceiling``."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

import slimseg
from slimseg.cli.main import main
from slimseg.data.collate import downsample_masks
from slimseg.data.synth import generate
from slimseg.detections import decode_rle, encode_rle
from slimseg.eval.boundary import MaskStack, band_width, boundary_band, boundary_iou
from slimseg.eval.ceiling import ceiling_detections, coarse_masks
from slimseg.eval.coco_eval import load_gt
from slimseg.eval.mask_quality import format_mask_quality_table, mask_quality
from slimseg.eval.postprocess import COCO_MAX_DETS
from slimseg.eval.skeleton import greedy_match, local_width, skeletonize
from slimseg.models.checkpoint import WeightsInfo, save_weights

HW = (64, 96)  # not square: a transposition slip shows


def _square(top: int, left: int, size: int = 10, hw: tuple[int, int] = HW) -> np.ndarray:
    m = np.zeros(hw, bool)
    m[top : top + size, left : left + size] = True
    return m


def _coco(frames: list[list[tuple[str, np.ndarray, int]]], names=("person", "sports ball")):
    """A COCO ground-truth dict: per image a list of ``(class, mask [H, W], iscrowd)``."""
    cats = {n: k + 1 for k, n in enumerate(names)}
    images, anns = [], []
    for i, objects in enumerate(frames, 1):
        images.append({"id": i, "file_name": f"{i}.png", "height": HW[0], "width": HW[1]})
        for name, mask, crowd in objects:
            rle = encode_rle(mask[None])[0]
            anns.append(
                {
                    "id": len(anns) + 1,
                    "image_id": i,
                    "category_id": cats[name],
                    "segmentation": rle,
                    "area": float(mask.sum()),
                    "bbox": [float(v) for v in mask_utils.toBbox(rle)],
                    "iscrowd": crowd,
                }
            )
    categories = [{"id": c, "name": n} for n, c in cats.items()]
    return {"images": images, "annotations": anns, "categories": categories}


def _det(img: int, cat: int, mask: np.ndarray, score: float = 1.0) -> dict:
    seg = encode_rle(mask[None])[0]
    return {"image_id": img, "category_id": cat, "segmentation": seg, "score": score}


def _bars(*bars: tuple[int, int, int, int]) -> np.ndarray:
    """A mask of filled rectangles ``(top, left, height, width)``."""
    m = np.zeros(HW, bool)
    for t, left, h, w in bars:
        m[t : t + h, left : left + w] = True
    return m


def _stick_person(top: int, left: int) -> np.ndarray:
    """Torso 14 × 8, 3-px arms and legs, a 6 × 6 head: about 20 × 40 px."""
    torso = (top + 8, left + 8, 14, 8)
    head = (top + 1, left + 9, 6, 6)
    arms = (top + 9, left, 3, 24)
    legs = [(top + 22, left + 8, 14, 3), (top + 22, left + 13, 14, 3)]
    return _bars(torso, head, arms, *legs)


# --- boundary bands ---------------------------------------------------------------------


def test_band_of_a_square_is_its_ring() -> None:
    sq = _square(20, 30)
    band = boundary_band(sq[None], 1)[0]
    assert band.sum() == 36
    inner = _square(21, 31, size=8)
    assert (band == (sq & ~inner)).all()
    # the image edge counts as background: a full frame's band is its outer ring
    full = np.ones((1, 5, 7), bool)
    assert boundary_band(full, 1)[0].sum() == 5 * 7 - 3 * 5
    assert boundary_band(sq[None], 5)[0].sum() == 100  # band wider than half: the whole mask


def test_boundary_iou_by_hand() -> None:
    a, b = _square(20, 30), _square(20, 31)  # b: shifted one column right
    assert boundary_iou(a, a, 1) == 1.0
    # d = 1: rings of 36 px sharing 9 + 9 pixels of the top and bottom rows: 18 / 54
    assert boundary_iou(a, b, 1) == pytest.approx(18 / 54)
    # d = 2: bands of 64 px; overlap = 90 shared px minus the two 6 × 6 cores (42 px): 48 / 80
    assert boundary_iou(a, b, 2) == pytest.approx(48 / 80)


def test_band_width_default() -> None:
    assert band_width((320, 320)) == 9 and band_width((480, 640)) == 16
    assert band_width((10, 10)) == 1  # never below one pixel


def test_mask_stack_bands_equal_the_dense_rule() -> None:
    rng = np.random.default_rng(0)
    masks = np.zeros((6, *HW), bool)
    for k in range(5):  # blobs, one touching the frame edge; the last mask stays empty
        y, x = rng.integers(0, HW[0] - 10), rng.integers(0, HW[1] - 10)
        masks[k, y : y + rng.integers(3, 30), x : x + rng.integers(3, 40)] = True
        masks[k] &= rng.random(HW) > 0.1
    masks[0, -3:, :20] = True
    stack = MaskStack(encode_rle(masks), HW)
    for k in range(len(masks)):
        assert (stack.mask(k) == masks[k]).all()
    for d in (1, 2, 7):
        got = decode_rle(stack.band_rles(d), HW)
        assert (got == boundary_band(masks, d)).all(), d


# --- skeletons and matching -------------------------------------------------------------


def test_skeleton_of_a_3px_bar_is_its_middle_row() -> None:
    bar = _bars((30, 10, 3, 20))
    skel = skeletonize(bar)
    rows, cols = np.nonzero(skel)
    # Zhang–Suen by hand: pass 1 strips the bottom row, right column and top-left corner,
    # then the top row and both ends of the middle row: columns 11..27 of row 31 remain
    assert set(rows) == {31} and cols.tolist() == list(range(11, 28))
    assert skel.sum() == 20 - 3
    assert local_width(bar)[31, 15] == 4.0  # 2 × the distance 2 to the background


def test_skeleton_is_transposition_equivariant_and_thin() -> None:
    person = _stick_person(10, 20)
    skel = skeletonize(person)
    assert (skeletonize(person.T) == skel.T).all()
    assert skel.any() and (skel <= person).all()
    # one pixel wide: no 2 × 2 block of skeleton pixels
    assert not (skel[:-1, :-1] & skel[1:, :-1] & skel[:-1, 1:] & skel[1:, 1:]).any()


def test_greedy_match_is_coco_style() -> None:
    ious = np.array([[0.6, 0.7], [0.0, 0.65], [0.55, 0.2]])
    scores = np.array([0.9, 0.8, 0.7])
    # det 0 takes gt 1 (its best); det 1's only match is taken; det 2 takes gt 0
    assert greedy_match(ious, scores).tolist() == [2, 0]
    assert greedy_match(ious, scores, threshold=0.66).tolist() == [-1, 0]
    assert greedy_match(np.zeros((0, 2)), np.zeros(0)).tolist() == [-1, -1]


# --- mask_quality -----------------------------------------------------------------------


def _scene() -> tuple[dict, list[dict]]:
    """Two images: stick people, balls, one crowd region; perfect detections of each."""
    frames = [
        [
            ("person", _stick_person(5, 5), 0),
            ("person", _stick_person(10, 50), 0),
            ("sports ball", _square(45, 80, 8), 0),
        ],
        [
            ("person", _stick_person(20, 30), 0),
            ("person", _bars((0, 0, 12, 12)), 1),  # crowd: an ignore zone
            ("sports ball", _square(2, 70, 12), 0),
        ],
    ]
    gt = _coco(frames)
    dets = [
        _det(a["image_id"], a["category_id"], decode_rle([a["segmentation"]], HW)[0])
        for a in gt["annotations"]
        if not a["iscrowd"]
    ]
    return gt, dets


def test_perfect_detections_score_one_everywhere() -> None:
    gt, dets = _scene()
    q = mask_quality(gt, dets)
    assert q["classes"] == ["person", "sports ball"] and q["instances"]["person"] == 3
    tables = [q["mask"], *q["boundary"].values()]
    assert list(q["boundary"]) == ["1px", "2px", "default"]
    for table in tables:
        for name in ("all", "person", "sports ball"):
            assert table[name] == {"ap": 1.0, "ap50": 1.0, "ap75": 1.0}, name
    sk = q["skeleton"]
    assert sk["recall"] == 1.0 and sk["thin_recall"] == 1.0 and sk["matched"] == 3
    assert 0 < sk["thin_pixels"] < sk["skeleton_pixels"]  # the torso is not thin
    assert q["settings"]["default_band_px"] == [band_width(HW)]
    text = format_mask_quality_table(q)
    assert text.splitlines()[2].startswith("person") and "skeleton recall" in text


def test_removed_limb_lowers_thin_recall_by_its_share() -> None:
    # a 9-px-wide trunk (never thin: width 10), a 3 × 40 and a 3 × 20 limb (37 and 17 thin
    # skeleton pixels, see the bar test); the detection misses the short limb
    trunk, long_limb, short_limb = (10, 5, 9, 40), (30, 5, 3, 40), (40, 60, 3, 20)
    gt = _coco([[("person", _bars(trunk, long_limb, short_limb), 0)]])
    full = mask_quality(gt, [_det(1, 1, _bars(trunk, long_limb, short_limb))])["skeleton"]
    cut = mask_quality(gt, [_det(1, 1, _bars(trunk, long_limb))])["skeleton"]
    assert full["thin_pixels"] == 37 + 17 and full["thin_recall"] == 1.0
    assert cut["matched"] == 1 and cut["thin_recall"] == pytest.approx(37 / 54)
    assert full["thin_recall"] - cut["thin_recall"] == pytest.approx(17 / 54)
    assert cut["recall"] == pytest.approx(1 - 17 / full["skeleton_pixels"])


def test_unmatched_people_cover_nothing_and_only_100_detections_count() -> None:
    gt = _coco([[("person", _stick_person(10, 20), 0)]])
    junk = [_det(1, 1, _square(50, 80, 4), 0.9) for _ in range(COCO_MAX_DETS)]
    perfect = _det(1, 1, _stick_person(10, 20), 0.1)  # 101st by score: COCO never reads it
    q = mask_quality(gt, [*junk, perfect])
    assert q["detections"] == COCO_MAX_DETS
    assert q["skeleton"]["recall"] == 0.0 and q["skeleton"]["matched"] == 0
    assert q["mask"]["person"]["ap"] == 0.0
    empty = mask_quality(gt, [])
    assert empty["mask"]["person"]["ap"] == 0.0 and empty["mask"]["sports ball"] is None
    assert empty["skeleton"]["recall"] == 0.0


@pytest.fixture(scope="module")
def synth(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny synthetic set at 320 px (thin limbs) with 8 val images."""
    out = tmp_path_factory.mktemp("mq") / "ds"
    return generate(out, 1, 8, 320, seed=0, progress=False).data_yaml


def _noisy_detections(gt: COCO, seed: int = 0) -> list[dict]:
    """Coarsened and shifted copies of the ground truth, some relabelled, random scores."""
    rng = np.random.default_rng(seed)
    out = []
    for img, info in gt.imgs.items():
        anns = gt.imgToAnns.get(img, [])
        masks = decode_rle([gt.annToRLE(a) for a in anns], (info["height"], info["width"]))
        for ratio in (1, 2, 4):
            for a, m in zip(anns, coarse_masks(masks, ratio), strict=True):
                dy, dx = (int(v) for v in rng.integers(-2, 3, 2)) if rng.random() < 0.5 else (0, 0)
                cat = a["category_id"] if rng.random() < 0.8 else int(rng.choice(list(gt.cats)))
                out.append(_det(img, cat, np.roll(m, (dy, dx), axis=(0, 1)), float(rng.random())))
    return out


def _pycocotools_stats(gt: COCO, dets: list[dict], cat: int) -> np.ndarray:
    with contextlib.redirect_stdout(io.StringIO()):
        ev = COCOeval(gt, gt.loadRes([dict(d) for d in dets]), "segm")
        ev.params.catIds = [cat]
        ev.evaluate()
        ev.accumulate()
        ev.summarize()
    return np.asarray(ev.stats[:3])


def test_per_class_and_boundary_ap_equal_pycocotools(synth: Path) -> None:
    gt = load_gt(synth.parent / "val" / "annotations.json")
    dets = _noisy_detections(gt)
    q = mask_quality(gt, dets, narrow_bands=(1, 60))
    for cat, info in gt.cats.items():
        got = q["mask"][info["name"]]
        want = _pycocotools_stats(gt, dets, cat)
        np.testing.assert_allclose([got["ap"], got["ap50"], got["ap75"]], want, atol=1e-12)
    # a 60 px band covers every synthetic object whole: boundary AP is mask AP
    assert q["boundary"]["60px"] == q["mask"]
    # the 1 px band equals pycocotools on masks replaced by their dense bands
    band_gt = load_gt(gt.dataset)
    for a in band_gt.dataset["annotations"]:
        m = decode_rle([band_gt.annToRLE(a)], (320, 320))
        a["segmentation"] = encode_rle(boundary_band(m, 1))[0]
    band_gt = load_gt(band_gt.dataset)
    band_dets = []
    for d in dets:
        band = boundary_band(decode_rle([d["segmentation"]], (320, 320)), 1)
        band_dets.append({**d, "segmentation": encode_rle(band)[0]})
    person = q["boundary"]["1px"]["person"]
    want = _pycocotools_stats(band_gt, band_dets, 1)
    np.testing.assert_allclose([person["ap"], person["ap50"], person["ap75"]], want, atol=1e-12)
    assert 0 < person["ap"] < q["mask"]["person"]["ap"]


# --- the ceiling ------------------------------------------------------------------------


def test_coarse_masks_follow_the_training_and_predictor_rules() -> None:
    masks = np.stack([_square(4, 4, 8), _square(5, 5, 8), _bars((3, 10, 26, 3))])
    for ratio in (2, 4):
        got = coarse_masks(masks, ratio)
        # the training targets' blocks, bilinear (half-pixel centres) back up, > 0.5, box crop
        cells = torch.from_numpy(downsample_masks(masks.astype(np.uint8), ratio)).float()
        up = F.interpolate(cells[:, None], size=HW, mode="bilinear", align_corners=False)
        boxes = masks.any(1)[:, None, :] & masks.any(2)[:, :, None]
        assert (got == ((up[:, 0] > 0.5).numpy() & boxes)).all(), ratio
    assert (coarse_masks(masks, 1) == masks).all()
    aligned = coarse_masks(_square(8, 8, 16)[None], 4)[0]
    assert aligned.sum() == 16 * 16 - 4  # grid-aligned: only the four corners are rounded


def test_ceiling_is_perfect_at_ratio_1_and_loses_thin_people_at_4(synth: Path) -> None:
    gt = load_gt(synth.parent / "val" / "annotations.json")
    exact = mask_quality(gt, ceiling_detections(gt, 1))
    assert exact["mask"]["all"] == {"ap": 1.0, "ap50": 1.0, "ap75": 1.0}
    assert exact["boundary"]["1px"]["all"]["ap"] == 1.0
    assert exact["skeleton"]["recall"] == 1.0 == exact["skeleton"]["thin_recall"]
    coarse = mask_quality(gt, ceiling_detections(gt, 4))
    person = coarse["mask"]["person"]["ap"]
    assert person < 0.7 and person < coarse["mask"]["all"]["ap"]  # people suffer most
    sk = coarse["skeleton"]
    assert sk["thin_recall"] < 0.9 and sk["thin_recall"] < sk["recall"] < 1.0
    assert coarse["boundary"]["1px"]["person"]["ap"] < 0.05


# --- CLI --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A 3-image synthetic val set at 64 px and an untrained yolov8n-seg that detects (class
    biases at 0), plus a detector for the error path."""
    root = tmp_path_factory.mktemp("mqcli")
    data = generate(root / "ds", 1, 3, 64, seed=1, progress=False).data_yaml
    names = ["person", "dog", "sports ball", "bottle", "chair", "tv"]
    paths = {"data": data}
    for spec in ("yolov8n-seg", "yolov8n"):
        torch.manual_seed(0)
        model = slimseg.build_model(spec, num_classes=len(names)).eval()
        with torch.no_grad():
            for branch in model.detect.cls:
                branch[-1].bias.fill_(0.0)
        info = WeightsInfo(model.spec, names, [1.0] * len(names), train_config={"imgsz": 64})
        paths[spec] = save_weights(root / f"{spec}.pt", model, info)
    return paths


def _run(capsys: pytest.CaptureFixture, *argv: str) -> tuple[int, str, str]:
    rc = main(["val", "--workers", "0", *argv])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_val_mask_quality_end_to_end(tiny: dict[str, Path], capsys: pytest.CaptureFixture) -> None:
    base = ["--weights", str(tiny["yolov8n-seg"]), "--data", str(tiny["data"])]
    rc, out, _ = _run(capsys, *base, "--json")
    assert rc == 0 and "mask_quality" not in json.loads(out)  # unchanged without the flag
    rc, out, _ = _run(capsys, *base, "--json", "--mask-quality")
    result = json.loads(out)
    assert rc == 0 and set(result) == {"box", "mask", "per_class", "speed_ms", "mask_quality"}
    q = result["mask_quality"]
    assert q["classes"][0] == "person" and list(q["boundary"]) == ["1px", "2px", "default"]
    assert q["detections"] > 0  # the untrained model does detect
    gt = load_gt(tiny["data"].parent / "val" / "annotations.json")
    people = sum(1 for a in gt.dataset["annotations"] if a["category_id"] == 1)
    assert q["skeleton"]["instances"] == people > 0
    tables = (q["mask"], *q["boundary"].values())
    values = [v for table in tables for entry in table.values() if entry for v in entry.values()]
    assert values and all(0.0 <= v <= 1.0 for v in values)
    rc, out, _ = _run(capsys, *base, "--mask-quality")
    assert rc == 0 and "bAP 1px" in out and "person skeleton recall" in out


def test_val_ceiling_and_errors(tiny: dict[str, Path], capsys: pytest.CaptureFixture) -> None:
    data = ["--data", str(tiny["data"])]
    rc, out, _ = _run(capsys, *data, "--ceiling", "1", "--json")
    result = json.loads(out)
    assert rc == 0 and result["ceiling_ratio"] == 1
    assert result["mask_quality"]["mask"]["all"] == {"ap": 1.0, "ap50": 1.0, "ap75": 1.0}
    rc, out, _ = _run(capsys, *data, "--ceiling", "4")
    assert rc == 0 and out.startswith("ceiling:") and "skeleton recall" in out
    for argv, needle in (
        ([*data, "--ceiling", "4", "--weights", str(tiny["yolov8n-seg"])], "drop --weights"),
        ([*data, "--ceiling", "0"], "must be >= 1"),
        (data, "--weights is required"),
        ([*data, "--weights", str(tiny["yolov8n"]), "--mask-quality"], "detector"),
    ):
        rc, _, err = _run(capsys, *argv)
        assert rc == 2 and needle in err and len(err.strip().splitlines()) == 1, argv
