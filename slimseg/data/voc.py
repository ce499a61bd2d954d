"""PASCAL VOC detection annotations to a COCO json (``slimseg data voc2coco``).

``voc_to_coco(voc_root, ["2007/trainval", "2012/trainval"])`` reads the image ids listed in
``<voc_root>/VOC<year>/ImageSets/Main/<set>.txt`` and their ``Annotations/<id>.xml``.
``voc_root`` is the ``VOCdevkit`` folder (or a folder containing ``VOCdevkit``); image
``file_name``s are relative to it (``VOC2007/JPEGImages/000005.jpg``), so a data config
uses that folder as ``images``.

Conventions:

* Boxes: VOC corners are 1-based inclusive pixel indices; the COCO box is
  ``[xmin - 1, ymin - 1, xmax - xmin + 1, ymax - ymin + 1]`` (0-based, continuous edges).
  Boxes are written as read (the loader clips and ``slimseg data check`` reports overflow).
* Boxes only: annotations have no ``segmentation`` key, so :class:`CocoDataset` uses the
  filled box as the mask and flags it in ``sample.meta["box_masks"]``.
* ``difficult`` objects (``difficult="ignore"``, the default) become ``iscrowd=1`` with
  ``difficult=1``: kept out of training, as darknet's VOC label script does for YOLO-SLAM,
  and ignored (neither true nor false positive) by evaluation, as in the VOC protocol.
  ``"train"`` keeps them as ordinary instances (``difficult=1`` still recorded), ``"drop"``
  leaves them out.
* Classes: the 20 VOC classes in the standard order, or the ``classes`` given (in that
  order; YOLO-SLAM uses ``person`` only); category ids ``1..K``. Images without any kept
  non-ignored object are dropped unless ``keep_unlabeled``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2

from slimseg.data.images import decode_file
from slimseg.errors import SlimsegError

VOC_CLASSES = (
    "aeroplane",
    "bicycle",
    "bird",
    "boat",
    "bottle",
    "bus",
    "car",
    "cat",
    "chair",
    "cow",
    "diningtable",
    "dog",
    "horse",
    "motorbike",
    "person",
    "pottedplant",
    "sheep",
    "sofa",
    "train",
    "tvmonitor",
)
DIFFICULT_MODES = ("ignore", "train", "drop")


@dataclass
class VocStats:
    """Counts of a conversion: per class (instances, difficult), images, skipped objects."""

    names: tuple[str, ...]
    instances: Counter = field(default_factory=Counter)
    difficult: Counter = field(default_factory=Counter)
    images_in: int = 0
    images_out: int = 0
    other_class: int = 0
    bad_boxes: list[str] = field(default_factory=list)

    def rows(self) -> list[list[object]]:
        """Table rows: id, name, instances, difficult."""
        return [[i + 1, n, self.instances[n], self.difficult[n]] for i, n in enumerate(self.names)]


def _voc_dir(voc_root: Path) -> Path:
    if not any(voc_root.glob("VOC[0-9]*")) and (voc_root / "VOCdevkit").is_dir():
        return voc_root / "VOCdevkit"
    return voc_root


def _parse_set(spec: str) -> tuple[str, str]:
    parts = spec.strip().strip("/").split("/")
    if len(parts) != 2 or not parts[0] or not parts[1]:
        raise SlimsegError(f"--sets {spec}: expected YEAR/SET, e.g. 2007/trainval")
    year = parts[0].removeprefix("VOC")
    return year, parts[1]


def _text(node: ET.Element | None, tag: str) -> str | None:
    child = node.find(tag) if node is not None else None
    return child.text.strip() if child is not None and child.text else None


def _number(node: ET.Element | None, tag: str, xml: Path) -> float:
    text = _text(node, tag)
    try:
        return float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise SlimsegError(f"{xml}: <{tag}> missing or not a number ({text!r})") from None


def voc_to_coco(
    voc_root: str | Path,
    sets: Sequence[str],
    classes: Sequence[str] | None = None,
    difficult: str = "ignore",
    keep_unlabeled: bool = False,
) -> tuple[dict, VocStats]:
    """Convert VOC sets to one COCO json dict (conventions in the module docstring)."""
    root = _voc_dir(Path(voc_root).expanduser())
    if not root.is_dir():
        raise SlimsegError(f"--voc-root {voc_root}: folder not found")
    if difficult not in DIFFICULT_MODES:
        raise SlimsegError(f"difficult={difficult!r}: use one of {', '.join(DIFFICULT_MODES)}")
    names = tuple(classes) if classes else VOC_CLASSES
    unknown = [c for c in names if c not in VOC_CLASSES]
    if unknown or len(set(names)) != len(names):
        raise SlimsegError(
            f"--classes {' '.join(names)}: unknown or repeated ({unknown}); VOC classes are "
            f"{', '.join(VOC_CLASSES)}"
        )
    cat_id = {n: i + 1 for i, n in enumerate(names)}
    stats = VocStats(names)
    images: list[dict] = []
    annotations: list[dict] = []
    seen: set[tuple[str, str]] = set()

    for spec in sets:
        year, set_name = _parse_set(spec)
        year_dir = root / f"VOC{year}"
        list_file = year_dir / "ImageSets" / "Main" / f"{set_name}.txt"
        if not list_file.is_file():
            raise SlimsegError(f"--sets {spec}: {list_file} not found")
        ids = [ln.split()[0] for ln in list_file.read_text().splitlines() if ln.strip()]
        for name in ids:
            if (year, name) in seen:
                continue
            seen.add((year, name))
            stats.images_in += 1
            xml = year_dir / "Annotations" / f"{name}.xml"
            if not xml.is_file():
                raise SlimsegError(f"{xml}: annotation file not found (listed in {list_file})")
            try:
                tree = ET.parse(xml).getroot()
            except ET.ParseError as exc:
                raise SlimsegError(f"{xml}: malformed XML ({exc})") from None
            file_name = _text(tree, "filename") or f"{name}.jpg"
            rel = f"VOC{year}/JPEGImages/{file_name}"
            size = tree.find("size")
            w = int(_number(size, "width", xml)) if _text(size, "width") else 0
            h = int(_number(size, "height", xml)) if _text(size, "height") else 0
            if w <= 0 or h <= 0:
                img = decode_file(root / rel, cv2.IMREAD_UNCHANGED)
                if img is None:
                    raise SlimsegError(f"{xml}: no <size> and image {root / rel} unreadable")
                h, w = img.shape[:2]
            image_id = len(images) + 1
            anns: list[dict] = []
            for obj in tree.findall("object"):
                cls = (_text(obj, "name") or "").strip()
                if cls not in cat_id:
                    stats.other_class += 1
                    continue
                is_difficult = _text(obj, "difficult") == "1"
                if is_difficult and difficult == "drop":
                    continue
                box = obj.find("bndbox")
                x0, y0 = _number(box, "xmin", xml) - 1, _number(box, "ymin", xml) - 1
                bw = _number(box, "xmax", xml) - x0
                bh = _number(box, "ymax", xml) - y0
                if bw <= 0 or bh <= 0:
                    stats.bad_boxes.append(f"{xml.name} ({cls})")
                    continue
                crowd = int(is_difficult and difficult == "ignore")
                anns.append(
                    {
                        "id": len(annotations) + len(anns) + 1,
                        "image_id": image_id,
                        "category_id": cat_id[cls],
                        "bbox": [x0, y0, bw, bh],
                        "area": bw * bh,
                        "iscrowd": crowd,
                        "difficult": int(is_difficult),
                        "truncated": int(_text(obj, "truncated") == "1"),
                    }
                )
            if not keep_unlabeled and not any(a["iscrowd"] == 0 for a in anns):
                continue
            for a in anns:
                stats.instances[names[a["category_id"] - 1]] += 1
                if a["difficult"]:
                    stats.difficult[names[a["category_id"] - 1]] += 1
            images.append(
                {
                    "id": image_id,
                    "file_name": rel,
                    "width": w,
                    "height": h,
                    "voc_id": f"{year}/{name}",
                }
            )
            annotations.extend(anns)
    stats.images_out = len(images)
    out = {
        "info": {
            "description": "PASCAL VOC converted by slimseg data voc2coco (boxes only)",
            "voc_root": str(root.resolve()),
            "sets": list(sets),
            "difficult": difficult,
            "keep_unlabeled": keep_unlabeled,
        },
        "images": images,
        "annotations": annotations,
        "categories": [{"id": i, "name": n, "supercategory": "voc"} for n, i in cat_id.items()],
    }
    return out, stats
