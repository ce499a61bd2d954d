"""COCO box and mask mAP with pycocotools, plus a per-class breakdown.

Numbers are pycocotools' own (101-point interpolated precision, area "all", at most 100
detections per image, IoU 0.50:0.05:0.95); YOLOv8's built-in validator computes its mAP
differently and typically reports slightly different values.

Choices:

* only the image ids passed to :meth:`CocoEvaluator.update` are evaluated
  (``params.imgIds``), so a partial validation run is a valid evaluation of that subset;
* only the categories of the contiguous → category-id mapping are evaluated
  (``params.catIds``): json categories left out of a model's ``names`` do not count;
* ground-truth annotations without ``iscrowd`` get 0, without ``area`` the area of their
  segmentation (box if none), and without segmentation (box instances, e.g. converted from
  VOC) the filled box as polygon, matching how the training data treats them;
* a class with no ground truth in the evaluated images gets ``None`` per class; the overall
  mAP averages over the classes that have ground truth (pycocotools' rule); when no class
  has any, or there is no detection at all, the overall mAP is 0.
"""

from __future__ import annotations

import contextlib
import io
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

from slimseg.data.coco_rle import segm_to_rle
from slimseg.detections import FrameDetections
from slimseg.errors import SlimsegError
from slimseg.eval.postprocess import COCO_MAX_DETS
from slimseg.utils.table import format_table

if TYPE_CHECKING:
    from slimseg.data.coco import CocoDataset

IOU_TYPES = ("bbox", "segm")
_RESULT_KEY = {"bbox": "box", "segm": "mask"}


def quiet(fn: Any, *args: Any) -> Any:
    """Call ``fn(*args)`` with pycocotools' stdout chatter swallowed."""
    with contextlib.redirect_stdout(io.StringIO()):
        return fn(*args)


def _fill_gt_defaults(data: dict) -> dict:
    """A copy of a COCO json dict whose annotations all have ``iscrowd``, ``bbox``,
    ``area`` and ``segmentation`` (see the module docstring); the input is not modified."""
    sizes = {im["id"]: (im["height"], im["width"]) for im in data["images"]}
    anns = []
    for ann in data["annotations"]:
        if ann.get("image_id") not in sizes:
            continue  # orphan annotation: never evaluated
        a = dict(ann)
        a.setdefault("iscrowd", 0)
        segm = a.get("segmentation")
        has_segm = bool(segm)
        needed = has_segm and ("bbox" not in a or "area" not in a)
        rle = segm_to_rle(segm, *sizes[a["image_id"]]) if needed else None
        if "bbox" not in a and has_segm:
            a["bbox"] = [float(v) for v in mask_utils.toBbox(rle)]
        if not has_segm and "bbox" in a:
            x, y, w, h = a["bbox"]
            a["segmentation"] = [[x, y, x + w, y, x + w, y + h, x, y + h]]
        if "area" not in a:
            if has_segm:
                a["area"] = float(mask_utils.area(rle))
            else:
                a["area"] = float(a["bbox"][2] * a["bbox"][3])
        anns.append(a)
    out = dict(data)
    out["annotations"] = anns
    return out


def load_gt(gt: str | Path | dict | COCO) -> COCO:
    """A :class:`~pycocotools.coco.COCO` of a json path, its loaded dict or another
    ``COCO`` (never modified), with the annotation defaults of the module docstring."""
    if isinstance(gt, COCO):
        data = gt.dataset
    elif isinstance(gt, dict):
        data = gt
    else:
        path = Path(gt)
        try:
            with open(path, encoding="utf-8") as f:
                data = json.load(f)
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise SlimsegError(f"{path}: cannot read the COCO ground-truth json ({exc})") from None
    if not all(isinstance(data.get(k), list) for k in ("images", "annotations", "categories")):
        raise SlimsegError("COCO ground truth needs 'images', 'annotations' and 'categories'")
    coco = COCO()
    coco.dataset = _fill_gt_defaults(data)
    quiet(coco.createIndex)
    return coco


class CocoEvaluator:
    """Accumulates frame detections and computes COCO box (``"bbox"``) / mask (``"segm"``) mAP.

    ``gt``: a COCO json path, its loaded dict, or a :class:`pycocotools.coco.COCO` (copied,
    never modified). ``cat_ids``: json category id of each contiguous class (a sequence
    indexed by class, e.g. ``CocoDataset.cat_ids``, or a ``{class: category_id}`` mapping
    covering ``0..K-1``). ``names``: class names (default: the json category names).
    ``iou_types``: ``("bbox", "segm")``, or ``("bbox",)`` for detection-only models.
    """

    def __init__(
        self,
        gt: str | Path | dict | COCO,
        cat_ids: Sequence[int] | Mapping[int, int],
        iou_types: Sequence[str] = IOU_TYPES,
        names: Sequence[str] | None = None,
    ) -> None:
        bad = [t for t in iou_types if t not in IOU_TYPES]
        if bad or not iou_types or "bbox" not in iou_types:
            raise ValueError(f"iou_types must be ('bbox',) or ('bbox', 'segm'), got {iou_types}")
        self.iou_types = tuple(dict.fromkeys(iou_types))
        self.gt = load_gt(gt)
        if isinstance(cat_ids, Mapping):
            if sorted(cat_ids) != list(range(len(cat_ids))):
                raise ValueError("a cat_ids mapping must cover the classes 0..K-1")
            cat_ids = [cat_ids[k] for k in range(len(cat_ids))]
        self.cat_ids = tuple(int(c) for c in cat_ids)
        unknown = [c for c in self.cat_ids if c not in self.gt.cats]
        if unknown or len(set(self.cat_ids)) != len(self.cat_ids):
            raise SlimsegError(
                f"category ids {unknown or self.cat_ids} are unknown or repeated in the "
                f"ground truth (json categories: {sorted(self.gt.cats)})"
            )
        self.names = (
            tuple(names)
            if names is not None
            else tuple(self.gt.cats[c]["name"] for c in self.cat_ids)
        )
        if len(self.names) != len(self.cat_ids):
            raise ValueError(f"{len(self.names)} names for {len(self.cat_ids)} classes")
        #: pycocotools' 12 summary numbers per iou type, filled by :meth:`summarize`.
        self.coco_stats: dict[str, np.ndarray] = {}
        self.reset()

    @classmethod
    def from_dataset(
        cls, dataset: CocoDataset, iou_types: Sequence[str] = IOU_TYPES
    ) -> CocoEvaluator:
        """An evaluator for a :class:`~slimseg.data.coco.CocoDataset`'s json and classes."""
        return cls(dataset.ground_truth, dataset.cat_ids, iou_types, dataset.names)

    def reset(self) -> None:
        """Forget every update (start a new evaluation)."""
        self._img_ids: list[int] = []
        self._seen: set[int] = set()
        self._results: dict[str, list[dict]] = {t: [] for t in self.iou_types}

    @property
    def num_images(self) -> int:
        return len(self._img_ids)

    @property
    def image_ids(self) -> list[int]:
        """The json image ids added since the last :meth:`reset`, in order."""
        return list(self._img_ids)

    def mask_results(self) -> list[dict]:
        """The accumulated mask detections as COCO result dicts (``image_id``,
        ``category_id``, ``segmentation`` RLE, ``score``), those whose mask was assembled
        (the ones COCO reads); empty for detection only."""
        return [dict(r) for r in self._results.get("segm", []) if r["segmentation"] is not None]

    def update(self, image_ids: Sequence[int], detections: Sequence[FrameDetections]) -> None:
        """Add the detections of images ``image_ids`` (json image ids, each at most once per
        evaluation; an image without detections still counts: pass an empty result)."""
        if len(image_ids) != len(detections):
            raise ValueError(f"{len(image_ids)} image ids for {len(detections)} results")
        for img_id, det in zip(image_ids, detections, strict=True):
            img_id = int(img_id)
            if img_id not in self.gt.imgs:
                raise SlimsegError(f"image id {img_id} is not in the ground-truth json")
            if img_id in self._seen:
                raise ValueError(f"image id {img_id} given twice in one evaluation")
            self._seen.add(img_id)
            self._img_ids.append(img_id)
            self._add(img_id, det)

    def _add(self, img_id: int, det: FrameDetections) -> None:
        n = len(det)
        if n == 0:
            return
        classes = det.classes.astype(np.int64)
        if classes.min() < 0 or classes.max() >= len(self.cat_ids):
            raise ValueError(f"class ids must be in 0..{len(self.cat_ids) - 1}")
        cats = [self.cat_ids[c] for c in classes]
        scores = det.scores.astype(float)
        xywh = det.boxes.astype(float).copy()
        xywh[:, 2:] -= xywh[:, :2]
        self._results["bbox"].extend(
            {"image_id": img_id, "category_id": c, "bbox": b, "score": s}
            for c, b, s in zip(cats, xywh.tolist(), scores.tolist(), strict=True)
        )
        if "segm" in self.iou_types:
            if not det.has_masks:
                raise ValueError("mask evaluation needs detections with masks (or RLEs)")
            rles = det.mask_rles()  # None: not assembled, beyond COCO_MAX_DETS of its class
            self._results["segm"].extend(
                {"image_id": img_id, "category_id": c, "segmentation": r, "score": s}
                for c, r, s in zip(cats, rles, scores.tolist(), strict=True)
            )

    def write_results(self, path: str | Path) -> Path:
        """Write the accumulated detections as a COCO results json (boxes xywh; masks as RLE
        under ``segmentation`` when evaluated, except for detections beyond
        :data:`~slimseg.eval.postprocess.COCO_MAX_DETS` of their class in an image, whose
        masks validation does not assemble), atomically."""
        merged: dict[int, dict] = {}
        for i, r in enumerate(self._results["bbox"]):
            merged[i] = dict(r)
        for i, r in enumerate(self._results.get("segm", [])):
            if r["segmentation"] is not None:  # no mask beyond COCO_MAX_DETS of its class
                merged[i]["segmentation"] = r["segmentation"]
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(json.dumps(list(merged.values())))
        tmp.replace(path)
        return path

    def _instances(self) -> list[int]:
        counts = dict.fromkeys(self.cat_ids, 0)
        for img_id in self._img_ids:
            for a in self.gt.imgToAnns.get(img_id, []):
                if a["category_id"] in counts and not a.get("iscrowd", 0):
                    counts[a["category_id"]] += 1
        return [counts[c] for c in self.cat_ids]

    def _evaluate(
        self, iou_type: str
    ) -> tuple[float, float, list[float | None], list[float | None]]:
        """Overall (mAP50-95, mAP50) and per-class lists for one iou type."""
        results = [r for r in self._results[iou_type] if r.get("segmentation", True) is not None]
        if not results:
            # No detection at all: pycocotools cannot load an empty result list. AP is 0 for
            # every class with ground truth.
            per = [0.0 if n else None for n in self._instances()]
            self.coco_stats[iou_type] = np.zeros(12)
            return 0.0, 0.0, per, list(per)
        dt = quiet(self.gt.loadRes, [dict(r) for r in results])  # loadRes adds keys
        ev = COCOeval(self.gt, dt, iou_type)
        ev.params.imgIds = sorted(self._img_ids)
        ev.params.catIds = sorted(self.cat_ids)
        if max(ev.params.maxDets) > COCO_MAX_DETS:  # the masks left out would then count
            raise ValueError(f"COCOeval scores {max(ev.params.maxDets)} detections per class")
        quiet(ev.evaluate)
        quiet(ev.accumulate)
        quiet(ev.summarize)
        stats = np.asarray(ev.stats, dtype=float)
        self.coco_stats[iou_type] = stats
        # precision [T iou thresholds, R recall points, K classes, A areas, M maxDets]
        prec = ev.eval["precision"][:, :, :, 0, -1]
        t50 = int(np.argmin(np.abs(ev.params.iouThrs - 0.5)))
        k_of = {c: k for k, c in enumerate(ev.params.catIds)}
        per_all: list[float | None] = []
        per_50: list[float | None] = []
        for c in self.cat_ids:
            p = prec[:, :, k_of[c]]
            valid = p[p > -1]
            per_all.append(float(valid.mean()) if valid.size else None)
            p50 = p[t50][p[t50] > -1]
            per_50.append(float(p50.mean()) if p50.size else None)
        return max(float(stats[0]), 0.0), max(float(stats[1]), 0.0), per_all, per_50

    def summarize(self) -> dict:
        """The metrics of everything added since the last :meth:`reset`::

            {"box": {"map50_95": x, "map50": y},
             "mask": {"map50_95": x, "map50": y} or None (detection only),
             "per_class": [{"class": name, "box_map50_95", "box_map50", "mask_map50_95",
                            "mask_map50", "instances": n}, ...]}   # contiguous class order

        Values are in ``[0, 1]``; per-class values are ``None`` for classes without ground
        truth in the evaluated images (and mask values ``None`` for detection only).
        """
        instances = self._instances()
        out: dict[str, Any] = {"box": None, "mask": None}
        per: dict[str, tuple[list, list]] = {}
        for t in self.iou_types:
            if self._img_ids:
                m, m50, pc, pc50 = self._evaluate(t)
            else:
                m, m50, pc, pc50 = 0.0, 0.0, [None] * len(self.cat_ids), [None] * len(self.cat_ids)
            out[_RESULT_KEY[t]] = {"map50_95": m, "map50": m50}
            per[_RESULT_KEY[t]] = (pc, pc50)
        none = [None] * len(self.cat_ids)
        box_all, box_50 = per["box"]
        mask_all, mask_50 = per.get("mask", (none, none))
        out["per_class"] = [
            {
                "class": self.names[k],
                "box_map50_95": box_all[k],
                "box_map50": box_50[k],
                "mask_map50_95": mask_all[k],
                "mask_map50": mask_50[k],
                "instances": instances[k],
            }
            for k in range(len(self.cat_ids))
        ]
        return out


def format_metrics_table(
    result: dict, names: Sequence[str] | None = None, markdown: bool = False
) -> str:
    """A per-class table of a :meth:`CocoEvaluator.summarize` result, ``all`` row first.

    Columns: class, instances, box mAP50-95, box mAP50 and, unless detection only, mask
    mAP50-95 and mask mAP50. ``names`` overrides the class names stored in ``result``.
    """
    with_mask = result.get("mask") is not None
    headers = ["class", "instances", "box mAP50-95", "box mAP50"]
    if with_mask:
        headers += ["mask mAP50-95", "mask mAP50"]
    per = result["per_class"]
    if names is not None and len(names) != len(per):
        raise ValueError(f"{len(names)} names for {len(per)} classes")

    def row(name: str, n: int, box: dict, mask: dict | None) -> list[object]:
        r: list[object] = [name, n, box["map50_95"], box["map50"]]
        if with_mask:
            r += [mask["map50_95"], mask["map50"]] if mask else [None, None]
        return r

    rows = [row("all", sum(e["instances"] for e in per), result["box"], result.get("mask"))]
    for k, e in enumerate(per):
        box = {"map50_95": e["box_map50_95"], "map50": e["box_map50"]}
        mask = {"map50_95": e["mask_map50_95"], "map50": e["mask_map50"]}
        rows.append(row(names[k] if names is not None else e["class"], e["instances"], box, mask))
    return format_table(headers, rows, markdown=markdown)
