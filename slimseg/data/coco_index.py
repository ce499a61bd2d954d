"""The COCO json index: images, instances and category mapping, parsed by the loading rules.

The rules are listed in ``slimseg.data.coco``; every problem is counted in a
:class:`~slimseg.data.problems.LoadReport`. No image is read here.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pycocotools import mask as mask_utils

from slimseg.data.problems import LoadReport
from slimseg.errors import SlimsegError
from slimseg.utils.input_files import check_regular
from slimseg.utils.outputs import escapes_root


@dataclass(slots=True)
class Instance:
    """One parsed annotation; ``box`` is clipped xyxy, ``segm`` as in the json (cleaned).

    ``segm`` is ``None`` (box instance), a list of polygon parts, or an RLE dict.
    """

    ann_id: int
    cls: int
    box: tuple[float, float, float, float]
    segm: Any
    crowd: bool


@dataclass(slots=True)
class ImageRecord:
    """One json image entry and its instances (training targets and crowd regions)."""

    id: int
    file_name: str
    width: int
    height: int
    instances: list[Instance] = field(default_factory=list)
    crowd: list[Instance] = field(default_factory=list)


@dataclass
class CocoIndex:
    """The parsed json: images in json order, class names and json category id per class."""

    images: list[ImageRecord]
    names: tuple[str, ...]
    cat_ids: tuple[int, ...]
    categories: list[dict]


def load_coco_json(path: str | Path) -> dict:
    """Read a COCO json and check its top-level structure (SlimsegError naming the file)."""
    path = Path(path)
    if not path.exists():
        raise SlimsegError(f"{path}: annotation file not found")
    check_regular(path, "annotation file")  # a FIFO would block the read
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except RecursionError:
        raise SlimsegError(f"{path}: not a readable JSON file (nested too deeply)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SlimsegError(f"{path}: not a readable JSON file ({exc})") from None
    if not isinstance(data, dict):
        raise SlimsegError(f"{path}: expected a COCO json object with 'images', 'annotations'")
    for key in ("images", "annotations", "categories"):
        if not isinstance(data.get(key), list):
            raise SlimsegError(f"{path}: '{key}' must be a list (is this a COCO instances json?)")
    for c in data["categories"]:
        if (
            not isinstance(c, dict)
            or not _is_int(c.get("id"))
            or not isinstance(c.get("name"), str)
        ):
            raise SlimsegError(f"{path}: every category needs an int 'id' and a 'name' ({c!r})")
    return data


def category_mapping(
    categories: Sequence[dict], names: Sequence[str] | None, source: str | Path
) -> tuple[tuple[str, ...], tuple[int, ...]]:
    """Class names and the json category id of each contiguous class ``0..K-1``.

    With ``names``, each name must match exactly one json category name; otherwise the json
    categories sorted by id. Raises SlimsegError naming ``source``.
    """
    ids = [int(c["id"]) for c in categories]
    if len(set(ids)) != len(ids):
        dup = sorted({i for i in ids if ids.count(i) > 1})
        raise SlimsegError(f"{source}: duplicate category ids {dup} in 'categories'")
    if names is None:
        cats = sorted(categories, key=lambda c: int(c["id"]))
        return tuple(str(c["name"]) for c in cats), tuple(int(c["id"]) for c in cats)
    by_name: dict[str, list[int]] = {}
    for c in categories:
        by_name.setdefault(str(c["name"]), []).append(int(c["id"]))
    missing = [n for n in names if n not in by_name]
    if missing:
        raise SlimsegError(
            f"{source}: class names {missing} not among the json categories "
            f"{sorted(by_name)}; fix 'names' in the data config"
        )
    ambiguous = [n for n in names if len(by_name[n]) > 1]
    if ambiguous:
        raise SlimsegError(f"{source}: category names {ambiguous} appear more than once")
    return tuple(names), tuple(by_name[n][0] for n in names)


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _polygon_area(p: Sequence[float]) -> float | None:
    """Shoelace area of a flat ``[x0, y0, x1, y1, ...]`` polygon; ``None`` if not numeric."""
    x, y = p[0::2], p[1::2]
    try:
        s = sum(a * b for a, b in zip(x, [*y[1:], *y[:1]], strict=True))
        s -= sum(a * b for a, b in zip(y, [*x[1:], *x[:1]], strict=True))
    except TypeError:
        return None
    return abs(s) * 0.5 if isinstance(s, (int, float)) and math.isfinite(s) else None


def _clean_segmentation(segm: Any, rec: ImageRecord, report: LoadReport, where: str) -> Any:
    """Return ``None`` (box instance), cleaned polygon parts, an RLE dict, or ``False`` (drop)."""
    if segm is None or (isinstance(segm, (list, dict)) and len(segm) == 0):
        return None
    if isinstance(segm, list):
        parts = [segm] if _is_num(segm[0]) else segm
        kept = []
        for part in parts:
            area = _polygon_area(part) if isinstance(part, list) and not len(part) % 2 else None
            if area is None:
                report.add("bad_segmentation", where)
            elif len(part) < 6:
                report.add("polygon_few_points", where)
            elif area <= 1e-6:
                report.add("polygon_zero_area", where)
            else:
                kept.append(part)
        return kept if kept else False
    if isinstance(segm, dict) and "counts" in segm and "size" in segm:
        size, counts = segm["size"], segm["counts"]
        if size != [rec.height, rec.width]:  # RLE of another image size (or malformed)
            report.add("bad_segmentation", where)
            return False
        if isinstance(counts, list):
            if (
                not all(_is_int(c) and c >= 0 for c in counts)
                or sum(counts) != rec.height * rec.width
            ):
                report.add("bad_segmentation", where)
                return False
            area = sum(counts[1::2])
        elif isinstance(counts, (str, bytes)):
            try:
                area = int(mask_utils.area({"size": size, "counts": counts}))
            except Exception:  # pycocotools raises bare Exceptions on bad strings
                report.add("bad_segmentation", where)
                return False
        else:
            report.add("bad_segmentation", where)
            return False
        if area == 0:
            report.add("empty_mask", where)
            return False
        return {"size": [rec.height, rec.width], "counts": counts}
    report.add("bad_segmentation", where)
    return False


def _segm_box(segm: Any) -> list[float] | None:
    """xywh of a cleaned segmentation (polygons or RLE), for annotations without ``bbox``."""
    if isinstance(segm, list):
        xs = [v for p in segm for v in p[0::2]]
        ys = [v for p in segm for v in p[1::2]]
        return [min(xs), min(ys), max(xs) - min(xs), max(ys) - min(ys)]
    if isinstance(segm, dict):
        rle = segm
        if isinstance(segm["counts"], list):
            rle = mask_utils.frPyObjects(segm, *segm["size"])
        return [float(v) for v in mask_utils.toBbox(rle)]
    return None


def parse_annotation(
    ann: dict,
    rec: ImageRecord,
    cat_to_cls: dict[int, int],
    json_cat_ids: set[int],
    report: LoadReport,
) -> Instance | None:
    """Apply the loading rules (module docstring) to one annotation of image ``rec``.

    Returns the instance, or ``None`` when it is dropped (the reason is added to ``report``).
    """
    where = f"{rec.file_name} (ann {ann.get('id')})"
    cid = ann.get("category_id")
    if cid not in json_cat_ids:
        report.add("unknown_category", f"{rec.file_name} (ann {ann.get('id')}, category {cid})")
        return None
    if cid not in cat_to_cls:
        report.add("category_not_selected", where)
        return None
    segm = _clean_segmentation(ann.get("segmentation"), rec, report, where)
    if segm is False:
        return None
    bbox = ann.get("bbox")
    if not (isinstance(bbox, list) and len(bbox) == 4 and all(_is_num(v) for v in bbox)):
        bbox = _segm_box(segm)
        if bbox is None:
            report.add("bad_annotation", where)
            return None
    x, y, w, h = (float(v) for v in bbox)
    if w <= 0 or h <= 0:
        report.add("box_outside", where)
        return None
    x0, y0 = min(max(x, 0.0), rec.width), min(max(y, 0.0), rec.height)
    x1, y1 = min(max(x + w, 0.0), rec.width), min(max(y + h, 0.0), rec.height)
    if x1 - x0 <= 0 or y1 - y0 <= 0:
        report.add("box_outside", where)
        return None
    if (x0, y0, x1, y1) != (x, y, x + w, y + h):
        report.add("box_clipped", where)
    crowd = bool(ann.get("iscrowd", 0))
    if crowd:
        report.add("crowd", where)
    elif segm is None:
        report.add("box_only", where)
    return Instance(int(ann["id"]), cat_to_cls[cid], (x0, y0, x1, y1), segm, crowd)


def build_index(
    data: dict, names: Sequence[str] | None, report: LoadReport, source: str | Path
) -> CocoIndex:
    """Parse a loaded COCO json (see :func:`load_coco_json`) into a :class:`CocoIndex`.

    Duplicate ids, malformed entries and every annotation-level rule are counted in
    ``report``; raises SlimsegError only if ``names`` do not match the json categories.
    """
    names_t, cat_ids = category_mapping(data["categories"], names, source)
    cat_to_cls = {cid: i for i, cid in enumerate(cat_ids)}
    json_cat_ids = {int(c["id"]) for c in data["categories"]}

    images: list[ImageRecord] = []
    by_id: dict[int, ImageRecord] = {}
    for im in data["images"]:
        ok = isinstance(im, dict) and _is_int(im.get("id")) and isinstance(im.get("file_name"), str)
        ok = ok and all(_is_int(im.get(k)) and im[k] > 0 for k in ("width", "height"))
        if not ok:
            where = im.get("file_name", repr(im)[:60]) if isinstance(im, dict) else repr(im)[:60]
            report.add("bad_image_entry", str(where))
            continue
        if im["id"] in by_id:
            report.add("duplicate_image_id", f"{im['file_name']} (id {im['id']})")
            continue
        if escapes_root(im["file_name"]):  # never read from outside the images folder
            report.add("path_outside_root", im["file_name"])
            continue
        rec = ImageRecord(im["id"], im["file_name"], im["width"], im["height"])
        by_id[rec.id] = rec
        images.append(rec)

    seen_ann: set[int] = set()
    for ann in data["annotations"]:
        if not (
            isinstance(ann, dict)
            and _is_int(ann.get("id"))
            and _is_int(ann.get("image_id"))
            and _is_int(ann.get("category_id"))
        ):
            report.add("bad_annotation", repr(ann)[:80])
            continue
        rec = by_id.get(ann["image_id"])
        if rec is None:
            report.add("orphan_annotation", f"ann {ann['id']} (image_id {ann['image_id']})")
            continue
        if ann["id"] in seen_ann:
            report.add("duplicate_annotation_id", f"{rec.file_name} (ann {ann['id']})")
        seen_ann.add(ann["id"])
        inst = parse_annotation(ann, rec, cat_to_cls, json_cat_ids, report)
        if inst is not None:
            (rec.crowd if inst.crowd else rec.instances).append(inst)
    for rec in images:
        if not rec.instances:
            report.add("image_without_annotations", rec.file_name)
    return CocoIndex(images, names_t, cat_ids, list(data["categories"]))
