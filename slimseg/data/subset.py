"""Class subsets of a COCO json (``slimseg data coco-subset``), e.g. COCO-20 of the paper.

The classes file (``configs/data/coco20.yaml``) lists ``classes: [{name, coco_id, mobility}]``
in the wanted order. The output json:

* ``categories``: ids ``1..K`` in the classes-file order, each with ``name`` (the classes
  file's), ``supercategory`` (the source's), ``coco_id`` (the source id) and ``mobility``;
* ``annotations``: those of kept classes, ``category_id`` remapped; ``iscrowd=1`` ones are
  kept (evaluation uses them as ignore regions; the loader keeps them out of training);
* ``images``: by default only images with at least one kept *non-crowd* annotation (their
  crowd annotations go with them). ``keep_unlabeled=True`` keeps every image, which for a
  val split gives the stricter evaluation on all images (false positives on images without
  any of the classes count). Image entries are copied unchanged: files are referenced by
  ``file_name``, never copied; ``info.slimseg_subset.images_dir`` records the source images
  folder when given.

Source categories are matched by ``coco_id``; a different name in the json only warns, and
a ``coco_id`` absent from the json falls back to matching by name (with a warning).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from slimseg.errors import SlimsegError
from slimseg.utils.atomic import write_json
from slimseg.utils.outputs import claim_file
from slimseg.utils.shipped import resolve_config
from slimseg.utils.yaml_io import read_yaml


@dataclass(frozen=True)
class ClassSpec:
    """One class of a subset: output name, source COCO category id, mobility prior."""

    name: str
    coco_id: int
    mobility: float


@dataclass
class SubsetStats:
    """What :func:`build_subset` kept: per-class counts (output order) and totals."""

    classes: list[ClassSpec]
    instances: list[int]
    crowd: list[int]
    images_per_class: list[int]
    images_in: int = 0
    images_out: int = 0
    annotations_in: int = 0
    annotations_out: int = 0
    warnings: list[str] = field(default_factory=list)

    def rows(self) -> list[list[object]]:
        """Table rows: id, name, coco_id, mobility, instances, crowd, images."""
        return [
            [i + 1, c.name, c.coco_id, c.mobility, n, cr, im]
            for i, (c, n, cr, im) in enumerate(
                zip(self.classes, self.instances, self.crowd, self.images_per_class, strict=True)
            )
        ]


def load_class_list(path: str | Path) -> list[ClassSpec]:
    """Read a classes file (``classes: [{name, coco_id, mobility}, ...]``)."""
    path = resolve_config(path, "data", "classes file")
    raw = read_yaml(path, "classes file")
    items = raw.get("classes") if isinstance(raw, dict) else None
    if not isinstance(items, list) or not items:
        raise SlimsegError(f"{path}: expected 'classes: [{{name, coco_id, mobility}}, ...]'")
    out: list[ClassSpec] = []
    for i, c in enumerate(items):
        where = f"{path}: classes[{i}]"
        if not isinstance(c, dict) or set(c) != {"name", "coco_id", "mobility"}:
            raise SlimsegError(f"{where}: needs exactly the keys name, coco_id, mobility")
        name, cid, mob = c["name"], c["coco_id"], c["mobility"]
        if not isinstance(name, str) or not name:
            raise SlimsegError(f"{where}: 'name' must be a non-empty string")
        if isinstance(cid, bool) or not isinstance(cid, int):
            raise SlimsegError(f"{where}: 'coco_id' must be an integer")
        if isinstance(mob, bool) or not isinstance(mob, (int, float)) or not 0 <= mob <= 1:
            raise SlimsegError(f"{where}: 'mobility' must be a number in [0, 1]")
        out.append(ClassSpec(name, cid, float(mob)))
    for attr in ("name", "coco_id"):
        values = [getattr(c, attr) for c in out]
        dup = sorted({v for v in values if values.count(v) > 1}, key=str)
        if dup:
            raise SlimsegError(f"{path}: duplicate {attr} {dup}")
    return out


def _match_categories(
    categories: Sequence[dict], classes: Sequence[ClassSpec], source: str
) -> tuple[dict[int, int], list[dict], list[str]]:
    """Source category id -> output id (1..K), output categories, warnings."""
    by_id = {c["id"]: c for c in categories if isinstance(c, dict) and "id" in c}
    by_name = {c.get("name"): c for c in categories if isinstance(c, dict)}
    remap: dict[int, int] = {}
    out: list[dict] = []
    warnings: list[str] = []
    for i, spec in enumerate(classes, start=1):
        cat = by_id.get(spec.coco_id)
        if cat is not None and cat.get("name") != spec.name:
            warnings.append(
                f"{source}: category id {spec.coco_id} is named '{cat.get('name')}' in the json, "
                f"'{spec.name}' in the classes file (matched by id)"
            )
        if cat is None:
            cat = by_name.get(spec.name)
            if cat is None:
                raise SlimsegError(
                    f"{source}: no category with id {spec.coco_id} or name '{spec.name}'; "
                    "is this a COCO instances json?"
                )
            warnings.append(
                f"{source}: no category id {spec.coco_id}; matched '{spec.name}' by name "
                f"(id {cat['id']})"
            )
        if cat["id"] in remap:
            raise SlimsegError(f"{source}: category {cat['id']} matched by two classes")
        remap[cat["id"]] = i
        out.append(
            {
                "id": i,
                "name": spec.name,
                "supercategory": cat.get("supercategory", ""),
                "coco_id": int(cat["id"]),
                "mobility": spec.mobility,
            }
        )
    return remap, out, warnings


def build_subset(
    data: dict,
    classes: Sequence[ClassSpec],
    keep_unlabeled: bool = False,
    images_dir: str | Path | None = None,
    source: str = "annotations",
) -> tuple[dict, SubsetStats]:
    """The subset json of a loaded COCO json (rules in the module docstring), with stats."""
    for key in ("images", "annotations", "categories"):
        if not isinstance(data.get(key), list):
            raise SlimsegError(f"{source}: '{key}' must be a list (is this a COCO instances json?)")
    remap, categories, warnings = _match_categories(data["categories"], classes, source)

    kept_anns: list[dict] = []
    labeled: set = set()
    for ann in data["annotations"]:
        new_id = remap.get(ann.get("category_id"))
        if new_id is None:
            continue
        kept_anns.append({**ann, "category_id": new_id})
        if not ann.get("iscrowd", 0):
            labeled.add(ann.get("image_id"))
    if keep_unlabeled:
        images = list(data["images"])
    else:
        images = [im for im in data["images"] if im.get("id") in labeled]
        kept_ids = {im.get("id") for im in images}
        kept_anns = [a for a in kept_anns if a.get("image_id") in kept_ids]

    k = len(classes)
    instances, crowd = [0] * k, [0] * k
    per_class_images: list[set] = [set() for _ in range(k)]
    for ann in kept_anns:
        c = ann["category_id"] - 1
        if ann.get("iscrowd", 0):
            crowd[c] += 1
        else:
            instances[c] += 1
            per_class_images[c].add(ann.get("image_id"))

    info = dict(data.get("info") or {})
    info["slimseg_subset"] = {
        "source": str(source),
        "classes": [c.name for c in classes],
        "keep_unlabeled": keep_unlabeled,
        "images_dir": str(Path(images_dir).expanduser().resolve()) if images_dir else None,
    }
    out = {
        "info": info,
        "licenses": data.get("licenses", []),
        "images": images,
        "annotations": kept_anns,
        "categories": categories,
    }
    stats = SubsetStats(
        classes=list(classes),
        instances=instances,
        crowd=crowd,
        images_per_class=[len(s) for s in per_class_images],
        images_in=len(data["images"]),
        images_out=len(images),
        annotations_in=len(data["annotations"]),
        annotations_out=len(kept_anns),
        warnings=warnings,
    )
    return out, stats


def _is_subset(path: Path) -> bool:
    """``path`` is a subset this module wrote (its ``info`` records ``slimseg_subset``)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    info = data.get("info") if isinstance(data, dict) else None
    return isinstance(info, dict) and "slimseg_subset" in info


def coco_subset(
    ann: str | Path,
    classes_file: str | Path,
    out_dir: str | Path,
    keep_unlabeled: bool = False,
    images_dir: str | Path | None = None,
) -> tuple[Path, SubsetStats]:
    """Read ``ann``, build the subset, write ``out_dir/<ann's file name>``; returns path, stats."""
    from slimseg.data.coco_index import load_coco_json

    ann = Path(ann).expanduser()
    classes = load_class_list(classes_file)
    if images_dir is not None and not Path(images_dir).expanduser().is_dir():
        raise SlimsegError(f"--images {images_dir}: folder not found")
    out_path = Path(out_dir).expanduser() / ann.name
    if out_path.resolve() == ann.resolve():
        raise SlimsegError(
            f"--out {out_dir}: would overwrite the source {ann}; pick another folder"
        )
    claim_file(out_path, "--out", _is_subset, "subset json")  # an earlier subset only
    data = load_coco_json(ann)
    subset, stats = build_subset(data, classes, keep_unlabeled, images_dir, source=str(ann))
    del data
    write_json(out_path, subset)
    return out_path, stats
