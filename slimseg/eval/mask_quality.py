"""Mask quality beyond mask mAP: per-class mask AP, Boundary AP at narrow bands, and skeleton
recall of people (does a model keep thin limbs?).

Entry points (definitions, band sizes and rules: docs/mask_quality.md):

* ``mask_quality(coco_gt, detections, *, narrow_bands=(1, 2), dilation_ratio=0.02,
  image_ids=None, cat_ids=None, person="person", thin_width=6.0) -> dict`` scores COCO
  result dicts (``image_id``, ``category_id``, RLE ``segmentation``, ``score``) against a
  ground truth (json path, dict or :class:`pycocotools.coco.COCO`); layout below;
* ``slimseg.eval.validation.validate_mask_quality(model, dataset, batch=8, workers=0,
  conf=EVAL_CONF, iou=NMS_IOU, progress=False, **mask_quality_options) -> dict`` runs an
  eval-mode model over a validation :class:`~slimseg.data.dataset.ZooDataset` (e.g. a
  trained sweep variant's val split) and returns ``mask_quality``'s dict for its detections;
* ``slimseg.eval.ceiling.ceiling_detections(coco_gt, ratio=4)``: the ground truth pushed
  through a ``ratio`` times coarser mask grid, the best such a grid allows;
* :func:`evaluator_mask_quality`: the same for the detections a
  :class:`~slimseg.eval.coco_eval.CocoEvaluator` accumulated (``slimseg val``);
* :func:`format_mask_quality_table`: the compact table ``slimseg val --mask-quality`` prints.

Boundary AP is COCO mask AP with every mask (ground truth and detection) replaced by its
inner boundary band (:mod:`slimseg.eval.boundary`): pycocotools then computes boundary IoU
where it computed mask IoU. Crowd ground truth keeps its full region (an ignore zone).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

from slimseg.errors import SlimsegError
from slimseg.eval.boundary import DILATION_RATIO, NARROW_BANDS, MaskStack, band_width
from slimseg.eval.coco_eval import CocoEvaluator, load_gt, quiet
from slimseg.eval.postprocess import COCO_MAX_DETS
from slimseg.eval.skeleton import MATCH_IOU, THIN_WIDTH, SkeletonTally, greedy_match
from slimseg.utils.table import format_table

#: The class whose ground truth skeleton recall is measured on.
PERSON = "person"
#: Key of the band of ``dilation_ratio × image diagonal`` under ``result["boundary"]``.
DEFAULT_BAND = "default"
_METRICS = ("ap", "ap50", "ap75")


def band_key(d: int) -> str:
    """Key of a narrow band of ``d`` pixels under ``result["boundary"]``: ``"1px"``."""
    return f"{d}px"


def _select(
    gt: COCO, detections: Iterable[dict], image_ids: set[int], cat_ids: set[int]
) -> dict[int, list[dict]]:
    """Per image, the detections COCO reads: those with a mask, of an evaluated image and
    class, the best :data:`COCO_MAX_DETS` per image and class (stable by score)."""
    groups: dict[tuple[int, int], list[dict]] = defaultdict(list)
    for det in detections:
        img, cat = int(det["image_id"]), int(det["category_id"])
        if img not in gt.imgs:
            raise ValueError(f"detection of image id {img}, which is not in the ground truth")
        if det.get("segmentation") is None or img not in image_ids or cat not in cat_ids:
            continue
        groups[img, cat].append(det)
    per_image: dict[int, list[dict]] = defaultdict(list)
    for (img, _), dets in groups.items():
        dets = sorted(dets, key=lambda d: -float(d["score"]))[:COCO_MAX_DETS]
        per_image[img].extend(dets)
    return per_image


def _instances(gt: COCO, image_ids: Sequence[int], cat_ids: Sequence[int]) -> dict[int, int]:
    """Non-crowd ground-truth instances per category id in the evaluated images."""
    counts = dict.fromkeys(cat_ids, 0)
    for img in image_ids:
        for a in gt.imgToAnns.get(img, []):
            if a["category_id"] in counts and not a.get("iscrowd", 0):
                counts[a["category_id"]] += 1
    return counts


def per_class_ap(
    gt: COCO, results: list[dict], image_ids: Sequence[int], cat_ids: Sequence[int]
) -> dict[int, dict[str, float] | None]:
    """COCO segm AP50:95, AP50 and AP75 of every category id from one evaluate/accumulate
    (pycocotools' precision array sliced per class; area "all", 100 detections), ``None``
    for a class without ground truth in ``image_ids``."""
    counts = _instances(gt, image_ids, cat_ids)
    if not results:  # pycocotools cannot load an empty result list: AP 0 where there is GT
        zero = dict.fromkeys(_METRICS, 0.0)
        return {c: dict(zero) if counts[c] else None for c in cat_ids}
    dt = quiet(gt.loadRes, [dict(r) for r in results])  # loadRes adds keys: copies
    ev = COCOeval(gt, dt, "segm")
    ev.params.imgIds = sorted(image_ids)
    ev.params.catIds = sorted(cat_ids)
    # only what is read: area "all" and 100 detections (the same numbers, ~4x less work)
    ev.params.areaRng, ev.params.areaRngLbl = ev.params.areaRng[:1], ev.params.areaRngLbl[:1]
    ev.params.maxDets = [COCO_MAX_DETS]
    quiet(ev.evaluate)
    quiet(ev.accumulate)
    prec = ev.eval["precision"][:, :, :, 0, -1]  # [T iou thresholds, R recall points, K]
    thr = ev.params.iouThrs
    t50, t75 = (int(np.argmin(np.abs(thr - t))) for t in (0.5, 0.75))
    out: dict[int, dict[str, float] | None] = {}
    for k, c in enumerate(ev.params.catIds):
        p = prec[:, :, k]
        if not (p > -1).any():
            out[c] = None
            continue
        out[c] = {
            "ap": float(p[p > -1].mean()),
            "ap50": float(p[t50][p[t50] > -1].mean()),
            "ap75": float(p[t75][p[t75] > -1].mean()),
        }
    return out


def _table(per_cat: dict[int, dict | None], names: dict[int, str], order: list[int]) -> dict:
    """``{"all": {ap, ap50, ap75}, name: {...} | None, ...}``; ``all`` averages the classes
    with ground truth (0 when none has any, as :class:`CocoEvaluator` does)."""
    valid = [v for v in per_cat.values() if v is not None]
    mean = {m: float(np.mean([v[m] for v in valid])) if valid else 0.0 for m in _METRICS}
    return {"all": mean, **{names[c]: per_cat[c] for c in order}}


def _tally_people(
    tally: SkeletonTally,
    people: list[tuple[dict, np.ndarray]],
    dets: list[dict],
    det_masks: list[np.ndarray],
    thin_width: float,
) -> None:
    """Add one image's person ground truths ``(rle, bool [H, W])`` to ``tally``, each with
    the mask of the person detection matched to it (:func:`greedy_match` on mask IoU)."""
    ious = np.zeros((len(dets), len(people)))
    if dets and people:
        segs = [d["segmentation"] for d in dets]
        ious = np.asarray(mask_utils.iou(segs, [r for r, _ in people], [0] * len(people)))
        ious = ious.reshape(len(dets), len(people))
    match = greedy_match(ious, np.array([float(d["score"]) for d in dets]), MATCH_IOU)
    for (_, gt_mask), k in zip(people, match.tolist(), strict=True):
        tally.add(gt_mask, det_masks[k] if k >= 0 else None, thin_width)


def _boundary_coco(gt: COCO, annotations: list[dict]) -> COCO:
    coco = COCO()
    coco.dataset = {
        "images": gt.dataset["images"],
        "categories": gt.dataset["categories"],
        "annotations": annotations,
    }
    quiet(coco.createIndex)
    return coco


def mask_quality(
    coco_gt: str | Path | dict | COCO,
    detections: Iterable[dict],
    *,
    narrow_bands: Sequence[int] = NARROW_BANDS,
    dilation_ratio: float = DILATION_RATIO,
    image_ids: Sequence[int] | None = None,
    cat_ids: Sequence[int] | None = None,
    person: str = PERSON,
    thin_width: float = THIN_WIDTH,
) -> dict:
    """Per-class mask AP, Boundary AP and person skeleton recall of COCO mask results.

    ``detections``: COCO result dicts with a compressed-RLE ``segmentation`` (``None``:
    skipped); only the best :data:`COCO_MAX_DETS` per image and class count, as in COCO.
    ``image_ids`` / ``cat_ids``: what is evaluated (default: every image / category of the
    ground truth). ``narrow_bands``: boundary band widths in pixels; the default band is
    ``max(1, round(dilation_ratio × diagonal))`` per image. Returns plain data::

        {"classes": [name, ...],                   # evaluated classes, person first
         "instances": {name: n, ...},              # non-crowd ground truth
         "detections": n,                          # the ones scored
         "mask": {"all": {"ap", "ap50", "ap75"}, name: {...} or None, ...},
         "boundary": {"1px": <as "mask">, "2px": ..., "default": ...},
         "skeleton": {"class": "person", "recall", "thin_recall", "instances", "matched",
                      "skeleton_pixels", "thin_pixels"} or None (no such class),
         "settings": {"narrow_bands", "dilation_ratio", "default_band_px", "thin_width",
                      "match_iou", "max_dets"}}

    AP values are in ``[0, 1]``, ``None`` for a class without ground truth; recalls are
    ``None`` without any skeleton pixel.
    """
    bands = [int(d) for d in narrow_bands]
    if any(d < 1 for d in bands) or len(set(bands)) != len(bands):
        raise ValueError(f"narrow_bands must be distinct widths >= 1 px, got {narrow_bands}")
    gt = load_gt(coco_gt)
    imgs = sorted(gt.imgs) if image_ids is None else sorted({int(i) for i in image_ids})
    cats = sorted(gt.cats) if cat_ids is None else sorted({int(c) for c in cat_ids})
    unknown = [i for i in imgs if i not in gt.imgs] + [c for c in cats if c not in gt.cats]
    if unknown:
        raise ValueError(f"image / category ids {unknown} are not in the ground truth")
    names = {c: str(gt.cats[c]["name"]) for c in cats}
    if len(set(names.values())) != len(names):
        raise ValueError(f"category names repeat in the ground truth: {sorted(names.values())}")
    person_cat = next((c for c in cats if names[c] == person), None)
    order = ([person_cat] if person_cat is not None else []) + [c for c in cats if c != person_cat]
    per_image = _select(gt, detections, set(imgs), set(cats))

    keys = [band_key(d) for d in bands] + [DEFAULT_BAND]
    b_gt: dict[str, list[dict]] = {k: [] for k in keys}
    b_dt: dict[str, list[dict]] = {k: [] for k in keys}
    default_px: set[int] = set()
    tally = SkeletonTally()
    cat_set = set(cats)
    for img in imgs:
        info = gt.imgs[img]
        hw = (int(info["height"]), int(info["width"]))
        anns = [a for a in gt.imgToAnns.get(img, []) if a["category_id"] in cat_set]
        crowd = [a for a in anns if a.get("iscrowd", 0)]
        plain = [a for a in anns if not a.get("iscrowd", 0)]
        gt_rles = [gt.annToRLE(a) for a in plain]
        gt_masks = MaskStack(gt_rles, hw)  # each mask decoded once
        dts = per_image.get(img, [])
        dt_masks = MaskStack([d["segmentation"] for d in dts], hw)
        widths = dict(zip(keys, [*bands, band_width(hw, dilation_ratio)], strict=True))
        default_px.add(widths[DEFAULT_BAND])
        encoded: dict[int, tuple[list[dict], list[dict]]] = {}
        for key, d in widths.items():
            if d not in encoded:
                encoded[d] = (gt_masks.band_rles(d), dt_masks.band_rles(d))
            g_rles, d_rles = encoded[d]
            b_gt[key] += [{**a, "segmentation": r} for a, r in zip(plain, g_rles, strict=True)]
            b_gt[key] += [dict(a) for a in crowd]  # ignore zones keep their full region
            b_dt[key] += [{**x, "segmentation": r} for x, r in zip(dts, d_rles, strict=True)]
        if person_cat is not None:
            gi = [i for i, a in enumerate(plain) if a["category_id"] == person_cat]
            di = [i for i, x in enumerate(dts) if x["category_id"] == person_cat]
            people = [(gt_rles[i], gt_masks.mask(i)) for i in gi]
            found = [dts[i] for i in di], [dt_masks.mask(i) for i in di]
            _tally_people(tally, people, *found, thin_width)

    all_dets = [d for img in imgs for d in per_image.get(img, [])]
    counts = _instances(gt, imgs, cats)
    skeleton = None
    if person_cat is not None:
        skeleton = {"class": person, **tally.summary()}
    return {
        "classes": [names[c] for c in order],
        "instances": {names[c]: counts[c] for c in order},
        "detections": len(all_dets),
        "mask": _table(per_class_ap(gt, all_dets, imgs, cats), names, order),
        "boundary": {
            k: _table(per_class_ap(_boundary_coco(gt, b_gt[k]), b_dt[k], imgs, cats), names, order)
            for k in keys
        },
        "skeleton": skeleton,
        "settings": {
            "narrow_bands": bands,
            "dilation_ratio": float(dilation_ratio),
            "default_band_px": sorted(default_px),
            "thin_width": float(thin_width),
            "match_iou": MATCH_IOU,
            "max_dets": COCO_MAX_DETS,
        },
    }


def format_mask_quality_table(result: dict, markdown: bool = False) -> str:
    """A :func:`mask_quality` result as a table (person first, ``all`` last: mask AP, AP50,
    AP75 and AP50:95 per boundary band) and one line of person skeleton recall."""
    keys = list(result["boundary"])
    px = result["settings"]["default_band_px"]
    default = f"{100 * result['settings']['dilation_ratio']:g}%diag"
    default += f" ({px[0]}px)" if len(px) == 1 else ""
    headers = ["class", "instances", "mask AP", "AP50", "AP75"] + [
        f"bAP {default if k == DEFAULT_BAND else k}" for k in keys
    ]
    rows: list[list[object]] = []
    for name in [*result["classes"], "all"]:
        mask = result["mask"][name]
        n = sum(result["instances"].values()) if name == "all" else result["instances"][name]
        row: list[object] = [name, n]
        row += [mask[m] if mask else None for m in _METRICS]
        row += [(result["boundary"][k][name] or {}).get("ap") for k in keys]
        rows.append(row)
    text = format_table(headers, rows, markdown=markdown)
    sk = result["skeleton"]
    if sk is None:
        return text + "\nskeleton recall: no person class in the ground truth"

    def fmt(v: float | None) -> str:
        return "-" if v is None else f"{v:.3f}"

    return text + (
        f"\n{sk['class']} skeleton recall: all {fmt(sk['recall'])}, thin (width <= "
        f"{result['settings']['thin_width']:g} px) {fmt(sk['thin_recall'])}  "
        f"({sk['matched']}/{sk['instances']} matched at mask IoU >= "
        f"{result['settings']['match_iou']:g}; {sk['skeleton_pixels']} skeleton px, "
        f"{sk['thin_pixels']} thin)"
    )


def evaluator_mask_quality(evaluator: CocoEvaluator, **options: Any) -> dict:
    """:func:`mask_quality` of the mask detections a :class:`CocoEvaluator` accumulated, on
    its images and classes (``options``: the keyword arguments of :func:`mask_quality`)."""
    if "segm" not in evaluator.iou_types:
        raise SlimsegError("mask quality needs mask detections: the model is a detector")
    return mask_quality(
        evaluator.gt,
        evaluator.mask_results(),
        image_ids=evaluator.image_ids,
        cat_ids=evaluator.cat_ids,
        **options,
    )
