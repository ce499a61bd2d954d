"""COCO-format instance datasets: json index, loading rules and mask decoding.

``CocoDataset(images_dir, annotations_json)`` yields :class:`~slimseg.data.sample.Sample`
objects. The index is built from the json alone at construction (no image is read), so a
dataset of 100k images opens in seconds; images are read on ``__getitem__``.

Loading rules (shared with ``slimseg data check``, which reports the same kinds):

* Images are read with ``cv2.IMREAD_UNCHANGED`` (EXIF orientation is *not* applied: COCO
  annotations refer to the stored pixel grid). Grayscale images are replicated to 3
  channels, RGBA drops the alpha channel (no compositing), 16-bit images are mapped to 8
  bits by ``round(v / 257)`` (full range to full range). Each conversion is counted in
  :attr:`CocoDataset.report`. A missing or undecodable file, or one whose size differs from
  the json's ``width``/``height``, raises :class:`~slimseg.errors.SlimsegError` naming it:
  run ``slimseg data check`` first to find them all at once.
* Segmentations may be polygons (a list of ``[x0, y0, x1, y1, ...]`` parts; several parts
  are merged into one mask), compressed RLE (``counts`` a string) or uncompressed RLE
  (``counts`` a list, column-major). Polygon parts with fewer than 3 points or zero area are
  dropped; an instance left without any part is dropped. RLEs whose ``size`` is not the
  image size are dropped. An instance whose mask decodes to no pixel is dropped.
* An annotation without segmentation (missing key, ``[]`` or ``null``; e.g. converted from
  VOC) is kept as a *box instance*: its mask is the filled box and
  ``sample.meta["box_masks"][i]`` is ``True``.
* Boxes (``bbox`` xywh; derived from the segmentation if absent) are clipped to the image;
  an instance whose box is empty (``w <= 0``/``h <= 0``, or nothing left after clipping) is
  dropped.
* ``iscrowd=1`` regions are never training targets: they go to ``sample.meta["crowd_*"]``
  (for ignore regions and evaluation).
* Category ids map to contiguous indices ``0..K-1``: in ``names`` order (matched by name to
  the json categories) if given, else the json categories sorted by id. Annotations of json
  categories not in ``names`` are skipped (counted as ``category_not_selected``);
  category ids absent from the json categories are dropped (``unknown_category``).

Problems found while indexing are counted at construction; per-image ones (conversions,
empty decoded masks) when the image is first loaded. With a multi-process ``DataLoader``
the latter are counted in the worker copies, so the main process only sees index-time
kinds: ``slimseg data check`` gives the complete picture.
"""

from __future__ import annotations

import json
import math
import warnings
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from pycocotools import mask as mask_utils

from slimseg.data.sample import Sample
from slimseg.errors import SlimsegError

if TYPE_CHECKING:
    from slimseg.data.config import DataConfig

ERROR, WARNING, INFO = "error", "warning", "info"

#: Every problem kind: (level, what it means and what the loader does).
KINDS: dict[str, tuple[str, str]] = {
    "missing_image": (ERROR, "image file not found"),
    "unreadable_image": (ERROR, "corrupt, unreadable or unsupported image file"),
    "size_mismatch": (ERROR, "json width/height differ from the image file"),
    "duplicate_image_id": (ERROR, "image id used twice (later entries ignored)"),
    "duplicate_annotation_id": (ERROR, "annotation id used twice (breaks COCO evaluation)"),
    "bad_image_entry": (ERROR, "image entry without int id / file_name / width / height"),
    "bad_annotation": (ERROR, "annotation without id / image_id / category_id / usable box"),
    "orphan_annotation": (ERROR, "annotation image_id not among the images (dropped)"),
    "unknown_category": (ERROR, "category_id not among the json categories (dropped)"),
    "bad_segmentation": (ERROR, "segmentation neither polygons nor a valid RLE (dropped)"),
    "names_mismatch": (ERROR, "a configured class name is not among the json categories"),
    "missing_depth": (ERROR, "depth file not found"),
    "bad_depth": (ERROR, "depth file unreadable, not 16-bit single channel, or wrong size"),
    "grayscale_image": (WARNING, "grayscale image converted to RGB"),
    "rgba_image": (WARNING, "image with alpha channel: alpha dropped"),
    "16bit_image": (WARNING, "16-bit image converted to 8 bits"),
    "polygon_few_points": (WARNING, "polygon part with < 3 points dropped"),
    "polygon_zero_area": (WARNING, "zero-area polygon part dropped"),
    "box_clipped": (WARNING, "box extends outside the image: clipped"),
    "box_outside": (WARNING, "box empty or entirely outside the image: annotation dropped"),
    "empty_mask": (WARNING, "mask has no pixel: annotation dropped"),
    "crowd": (INFO, "iscrowd=1 region: kept out of the training targets"),
    "box_only": (INFO, "no segmentation: the filled box is the mask"),
    "category_not_selected": (INFO, "json category not in names: annotation skipped"),
    "image_without_annotations": (INFO, "image without any training instance"),
}


def kind_level(kind: str) -> str:
    """``"error"``, ``"warning"`` or ``"info"`` for a problem kind (unknown kinds: error)."""
    return KINDS.get(kind, (ERROR, ""))[0]


class LoadReport(Counter):
    """Counts per problem kind, plus example locations (file names) per kind.

    A :class:`collections.Counter` (``report["box_clipped"]``) with ``examples[kind]``: the
    first ``max_examples`` locations (``None``: keep all).
    """

    def __init__(self, max_examples: int | None = 5) -> None:
        super().__init__()
        self.max_examples = max_examples
        self.examples: dict[str, list[str]] = {}

    def add(self, kind: str, where: str = "", n: int = 1) -> None:
        """Count ``n`` occurrences of ``kind`` at location ``where`` (a file name)."""
        self[kind] += n
        ex = self.examples.setdefault(kind, [])
        if where and (self.max_examples is None or len(ex) < self.max_examples):
            ex.append(where)

    def level_counts(self) -> dict[str, int]:
        """Total count per level (``error``/``warning``/``info``)."""
        out = {ERROR: 0, WARNING: 0, INFO: 0}
        for kind, n in self.items():
            out[kind_level(kind)] += n
        return out

    def summary(self, levels: Iterable[str] = (ERROR, WARNING)) -> str:
        """One line per kind of the given levels, e.g. for the trainer's log."""
        wanted = set(levels)
        lines = []
        for kind, n in sorted(self.items()):
            if kind_level(kind) in wanted and n:
                ex = ", ".join(self.examples.get(kind, [])[:3])
                lines.append(f"{kind_level(kind)} {kind}: {n}" + (f" (e.g. {ex})" if ex else ""))
        return "\n".join(lines)


class ImageProblem(SlimsegError):
    """An image (or depth) file that cannot be used; ``kind`` is a :data:`KINDS` key."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


# ----------------------------------------------------------------------------- images


def _imdecode(path: Path, flags: int) -> np.ndarray | None:
    try:
        buf = np.fromfile(path, dtype=np.uint8)
    except OSError:
        return None
    if buf.size == 0:
        return None
    return cv2.imdecode(buf, flags)


def _read_unchanged(path: Path, what: str, missing: str, unreadable: str) -> np.ndarray:
    """Decode ``path`` as stored (any depth/channels); ImageProblem of kind ``missing`` or
    ``unreadable`` with the same messages for images and depth maps."""
    if not path.is_file():
        raise ImageProblem(missing, f"{path}: {what} file not found")
    array = _imdecode(path, cv2.IMREAD_UNCHANGED)
    if array is None:
        raise ImageProblem(unreadable, f"{path}: corrupt or unreadable {what} file")
    return array


def read_image_rgb8(path: str | Path) -> tuple[np.ndarray, list[str]]:
    """Read an image file as ``uint8 [H, W, 3]`` RGB.

    Returns the image and the conversion kinds applied (``grayscale_image``, ``rgba_image``,
    ``16bit_image``). Raises :class:`ImageProblem` (``missing_image`` / ``unreadable_image``).
    """
    path = Path(path)
    img = _read_unchanged(path, "image", "missing_image", "unreadable_image")
    notes: list[str] = []
    if img.dtype == np.uint16:
        img = np.round(img.astype(np.float32) / 257.0).astype(np.uint8)
        notes.append("16bit_image")
    elif img.dtype != np.uint8:
        raise ImageProblem(
            "unreadable_image", f"{path}: unsupported pixel type {img.dtype} (need 8/16-bit)"
        )
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] == 2:  # gray + alpha
        img = img[:, :, 0]
        notes.append("rgba_image")
    if img.ndim == 2:
        notes.append("grayscale_image")
        return np.ascontiguousarray(np.repeat(img[:, :, None], 3, axis=2)), notes
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ImageProblem("unreadable_image", f"{path}: unsupported image shape {img.shape}")
    if img.shape[2] == 4:
        notes.append("rgba_image")
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB), notes
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB), notes  # a plain channel swap, SIMD


def read_depth(path: str | Path, height: int, width: int) -> np.ndarray:
    """Read a depth map as ``uint16 [H, W]``; raises :class:`ImageProblem` on any mismatch."""
    path = Path(path)
    depth = _read_unchanged(path, "depth", "missing_depth", "bad_depth")
    if depth.dtype != np.uint16 or depth.ndim != 2 or depth.shape != (height, width):
        raise ImageProblem(
            "bad_depth",
            f"{path}: depth must be 16-bit single-channel {width}x{height}, got {depth.dtype} "
            f"{depth.shape}",
        )
    return depth


def depth_path_for(depth_dir: Path, file_name: str) -> Path:
    """The depth file of an image: same relative path, ``.png`` suffix, under ``depth_dir``."""
    return depth_dir / Path(file_name).with_suffix(".png")


# ----------------------------------------------------------------------------- index


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
    if not path.is_file():
        raise SlimsegError(f"{path}: annotation file not found")
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
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


# ----------------------------------------------------------------------------- masks


def _box_pixels(box: tuple[float, ...], height: int, width: int) -> tuple[int, int, int, int]:
    """Rows ``r0:r1`` and columns ``c0:c1`` of a filled box mask (at least one pixel)."""
    x0, y0, x1, y1 = box
    c0 = min(round(x0), width - 1)
    r0 = min(round(y0), height - 1)
    c1 = min(max(round(x1), c0 + 1), width)
    r1 = min(max(round(y1), r0 + 1), height)
    return r0, r1, c0, c1


def segm_to_rle(segm: list | dict, height: int, width: int) -> dict:
    """Polygons (merged), uncompressed or compressed RLE → one compressed RLE."""
    if isinstance(segm, list):
        return mask_utils.merge(mask_utils.frPyObjects(segm, height, width))
    if isinstance(segm["counts"], list):
        return mask_utils.frPyObjects(segm, height, width)
    return segm


def decode_instance_mask(inst: Instance, height: int, width: int) -> np.ndarray:
    """The ``uint8 [H, W]`` 0/1 mask of a parsed instance (filled box for box instances)."""
    segm = inst.segm
    if segm is None:
        r0, r1, c0, c1 = _box_pixels(inst.box, height, width)
        m = np.zeros((height, width), np.uint8)
        m[r0:r1, c0:c1] = 1
        return m
    rle = segm_to_rle(segm, height, width)
    with warnings.catch_warnings():
        # pycocotools' Cython array lacks numpy 2's ``copy`` keyword: harmless, silenced here.
        warnings.filterwarnings("ignore", "__array__ implementation", DeprecationWarning)
        return np.ascontiguousarray(mask_utils.decode(rle), dtype=np.uint8)


def decode_instance_masks(insts: Sequence[Instance], height: int, width: int) -> np.ndarray:
    """``uint8 [N, H, W]``: :func:`decode_instance_mask` of each instance, with one
    pycocotools call for all RLE instances and a SIMD transpose out of its column-major
    layout (the same pixels, several times faster than one decode and copy per mask)."""
    out = np.empty((len(insts), height, width), np.uint8)
    rle_at = [k for k, inst in enumerate(insts) if inst.segm is not None]
    for k, inst in enumerate(insts):
        if inst.segm is None:
            out[k] = decode_instance_mask(inst, height, width)
    if rle_at:
        rles = [segm_to_rle(insts[k].segm, height, width) for k in rle_at]
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "__array__ implementation", DeprecationWarning)
            columns = mask_utils.decode(rles).T  # [N, W, H], C-contiguous
        for j, k in enumerate(rle_at):
            cv2.transpose(columns[j], dst=out[k])
    return out


def instance_area(inst: Instance, height: int, width: int) -> int:
    """Pixel count of an instance's mask, computed on its RLE (no dense decode)."""
    segm = inst.segm
    if segm is None:
        r0, r1, c0, c1 = _box_pixels(inst.box, height, width)
        return (r1 - r0) * (c1 - c0)
    rle = segm_to_rle(segm, height, width)
    return int(mask_utils.area(rle))


def _boxes(insts: list[Instance]) -> np.ndarray:
    return np.asarray([i.box for i in insts], np.float32).reshape(-1, 4)


# ----------------------------------------------------------------------------- dataset


class CocoDataset:
    """Instances of a COCO-format json as :class:`Sample` objects (torch Dataset protocol).

    ``images_dir / file_name`` is each image's path; ``depth_dir`` (optional) holds a
    ``uint16`` PNG per image at the same relative path with suffix ``.png`` (a missing depth
    file gives ``sample.depth = None`` and a ``missing_depth`` count). See the module
    docstring for the loading rules.

    ``sample.meta``: ``file_name``; ``ann_ids`` ``int64 [N]``; ``box_masks`` ``bool [N]``
    (``True``: no segmentation, mask = filled box); ``crowd_masks`` ``uint8 [M, H, W]``,
    ``crowd_boxes`` ``float32 [M, 4]`` xyxy, ``crowd_classes`` ``int64 [M]`` (iscrowd
    regions, excluded from the targets); ``converted`` (list of conversion kinds).

    Attributes: ``names`` (class names, index = class id), ``cat_ids`` (json category id per
    class), ``report`` (:class:`LoadReport`), ``records`` (the :class:`ImageRecord` list).
    """

    def __init__(
        self,
        images_dir: str | Path,
        annotations_json: str | Path,
        names: Sequence[str] | None = None,
        depth_dir: str | Path | None = None,
    ) -> None:
        self.images_dir = Path(images_dir)
        self.annotations_json = Path(annotations_json)
        self.depth_dir = Path(depth_dir) if depth_dir is not None else None
        if not self.images_dir.is_dir():
            raise SlimsegError(f"{self.images_dir}: images folder not found")
        if self.depth_dir is not None and not self.depth_dir.is_dir():
            raise SlimsegError(f"{self.depth_dir}: depth folder not found")
        self.report = LoadReport()
        data = load_coco_json(self.annotations_json)
        index = build_index(data, names, self.report, self.annotations_json)
        self.records = index.images
        self.names = index.names
        self.cat_ids = index.cat_ids
        self.categories = index.categories
        self._reported: set[int] = set()

    @classmethod
    def from_config(cls, config: DataConfig, split: str = "train") -> CocoDataset:
        """The ``split`` (``"train"``/``"val"``) of a :class:`~slimseg.data.config.DataConfig`."""
        s = config.split(split)
        return cls(s.images, s.annotations, names=config.names, depth_dir=s.depth)

    @property
    def num_classes(self) -> int:
        return len(self.names)

    def __len__(self) -> int:
        return len(self.records)

    def image_path(self, index: int) -> Path:
        """Absolute path of image ``index``."""
        return self.images_dir / self.records[index].file_name

    def __getitem__(self, index: int) -> Sample:
        if index < 0:
            index += len(self.records)
        if not 0 <= index < len(self.records):
            raise IndexError(f"index {index} out of range for {len(self.records)} images")
        rec = self.records[index]
        path = self.images_dir / rec.file_name
        first = index not in self._reported
        self._reported.add(index)
        image, notes = read_image_rgb8(path)
        h, w = image.shape[:2]
        if (w, h) != (rec.width, rec.height):
            raise SlimsegError(
                f"{path}: image is {w}x{h} but {self.annotations_json.name} says "
                f"{rec.width}x{rec.height}; run 'slimseg data check' and fix the json"
            )
        if first:
            for kind in notes:
                self.report.add(kind, rec.file_name)

        decoded = decode_instance_masks(rec.instances, h, w)
        nonempty = decoded.any(axis=(1, 2))
        if first:
            for inst, ok in zip(rec.instances, nonempty, strict=True):
                if not ok:
                    self.report.add("empty_mask", f"{rec.file_name} (ann {inst.ann_id})")
        kept = [inst for inst, ok in zip(rec.instances, nonempty, strict=True) if ok]
        masks = decoded if nonempty.all() else decoded[nonempty]
        crowd_masks = decode_instance_masks(rec.crowd, h, w)

        depth = None
        if self.depth_dir is not None:
            try:
                depth = read_depth(depth_path_for(self.depth_dir, rec.file_name), h, w)
            except ImageProblem as exc:
                if exc.kind != "missing_depth":
                    raise
                if first:
                    self.report.add("missing_depth", rec.file_name)

        return Sample(
            image=image,
            boxes=_boxes(kept),
            classes=np.asarray([i.cls for i in kept], np.int64),
            masks=masks,
            image_id=rec.id,
            path=str(path),
            depth=depth,
            meta={
                "file_name": rec.file_name,
                "ann_ids": np.asarray([i.ann_id for i in kept], np.int64),
                "box_masks": np.asarray([i.segm is None for i in kept], bool),
                "crowd_masks": crowd_masks,
                "crowd_boxes": _boxes(rec.crowd),
                "crowd_classes": np.asarray([c.cls for c in rec.crowd], np.int64),
                "converted": notes,
            },
        )
