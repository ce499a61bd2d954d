"""Dataset configs (``data.yaml``): where a COCO-format dataset lives and what its classes are.

Schema::

    path: ROOT            # optional. Relative paths below resolve against it; itself relative
                          # to the yaml's folder ('~' expanded). Default: the yaml's folder.
    train:                # optional if val is given
      images: DIR         # folder that file_name in the json is relative to
      annotations: FILE   # COCO instances json
      depth: DIR          # optional: uint16 PNG depth per image, same relative path, .png
    val:                  # optional if train is given; same keys as train
      images: DIR
      annotations: FILE
    names: [a, b, ...]    # optional. Class i = names[i], matched *by name* to the json
                          # categories. Default: the json categories sorted by id.
    mobility: [1.0, ...]  # optional. Mobility prior in [0, 1] per class, same order as names,
                          # or a mapping {name: prior} covering every class. Default: the
                          # json categories' 'mobility' fields (written by
                          # 'slimseg data coco-subset'), else none (empty tuple).

Default names and mobility come from the val json (usually the smaller one), else train.
Every problem (unknown key, missing file or folder, bad names or mobility) raises
:class:`~slimseg.errors.SlimsegError` naming the yaml and the field.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from slimseg.errors import SlimsegError
from slimseg.utils.shipped import resolve_config
from slimseg.utils.yaml_io import read_yaml

_TOP_KEYS = {"path", "train", "val", "names", "mobility"}
_SPLIT_KEYS = {"images", "annotations", "depth"}
SPLITS = ("train", "val")


@dataclass(frozen=True)
class SplitConfig:
    """One split: images folder, COCO json, optional depth folder (all absolute paths)."""

    images: Path
    annotations: Path
    depth: Path | None = None


@dataclass(frozen=True)
class DataConfig:
    """A loaded ``data.yaml``: resolved paths, class names and mobility priors.

    ``mobility`` is empty when neither the yaml nor the json gives priors; otherwise it has
    one float in ``[0, 1]`` per name.
    """

    root: Path
    train: SplitConfig | None
    val: SplitConfig | None
    names: tuple[str, ...]
    mobility: tuple[float, ...]
    source: Path

    @property
    def num_classes(self) -> int:
        return len(self.names)

    def split(self, name: str) -> SplitConfig:
        """The ``train`` or ``val`` split; SlimsegError if the yaml does not define it."""
        if name not in SPLITS:
            raise SlimsegError(f"unknown split '{name}' (use one of {', '.join(SPLITS)})")
        s = getattr(self, name)
        if s is None:
            raise SlimsegError(f"{self.source}: no '{name}' split; add '{name}:' to the yaml")
        return s


def _err(src: Path, field: str, msg: str) -> SlimsegError:
    return SlimsegError(f"{src}: '{field}': {msg}")


def _resolve(base: Path, value: Any, src: Path, field: str) -> Path:
    if not isinstance(value, str) or not value.strip():
        raise _err(src, field, f"expected a path string, got {value!r}")
    p = Path(value).expanduser()
    return (p if p.is_absolute() else base / p).resolve()


def _split(raw: Any, root: Path, src: Path, name: str) -> SplitConfig:
    if not isinstance(raw, Mapping):
        raise _err(src, name, "expected a mapping with 'images' and 'annotations'")
    unknown = set(raw) - _SPLIT_KEYS
    if unknown:
        raise _err(src, name, f"unknown keys {sorted(unknown)} (allowed: {sorted(_SPLIT_KEYS)})")
    for key in ("images", "annotations"):
        if key not in raw:
            raise _err(src, f"{name}.{key}", "missing")
    images = _resolve(root, raw["images"], src, f"{name}.images")
    if not images.is_dir():
        raise _err(src, f"{name}.images", f"folder {images} not found")
    ann = _resolve(root, raw["annotations"], src, f"{name}.annotations")
    if not ann.is_file():
        raise _err(src, f"{name}.annotations", f"file {ann} not found")
    depth = None
    if raw.get("depth") is not None:
        depth = _resolve(root, raw["depth"], src, f"{name}.depth")
        if not depth.is_dir():
            raise _err(src, f"{name}.depth", f"folder {depth} not found")
    return SplitConfig(images, ann, depth)


def _json_categories(path: Path, src: Path, field: str) -> list[dict]:
    try:
        with open(path, encoding="utf-8") as f:
            cats = json.load(f).get("categories")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError) as exc:
        raise _err(src, field, f"cannot read categories from {path} ({exc})") from None
    if not isinstance(cats, list) or not all(
        isinstance(c, dict) and isinstance(c.get("id"), int) and isinstance(c.get("name"), str)
        for c in cats
    ):
        raise _err(src, field, f"{path} has no valid 'categories' list (id, name)")
    return cats


def _prior(v: Any, src: Path, field: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0:
        raise _err(src, field, f"mobility prior must be a number in [0, 1], got {v!r}")
    return float(v)


def load_data_config(path: str | Path) -> DataConfig:
    """Load and validate a dataset yaml (schema in the module docstring)."""
    src = resolve_config(path, "data", "data config").resolve()
    raw = read_yaml(src, "data config")
    if not isinstance(raw, Mapping):
        raise SlimsegError(
            f"{src}: expected a mapping with 'train'/'val' (see slimseg.data.config)"
        )
    unknown = set(raw) - _TOP_KEYS
    if unknown:
        raise SlimsegError(
            f"{src}: unknown keys {sorted(unknown)} (allowed: {', '.join(sorted(_TOP_KEYS))})"
        )
    root = src.parent
    if raw.get("path") is not None:
        root = _resolve(src.parent, raw["path"], src, "path")
        if not root.is_dir():
            raise _err(src, "path", f"folder {root} not found")
    splits = {s: _split(raw[s], root, src, s) for s in SPLITS if raw.get(s) is not None}
    if not splits:
        raise SlimsegError(f"{src}: needs a 'train' and/or 'val' split")
    ref_split = "val" if "val" in splits else "train"
    ref_json = splits[ref_split].annotations

    cats: list[dict] | None = None
    names_raw = raw.get("names")
    if names_raw is None:
        cats = _json_categories(ref_json, src, f"{ref_split}.annotations")
        names = tuple(str(c["name"]) for c in sorted(cats, key=lambda c: c["id"]))
        if not names:
            raise _err(src, "names", f"not given and {ref_json} has no categories")
    else:
        if not isinstance(names_raw, list) or not names_raw:
            raise _err(src, "names", "expected a non-empty list of class names")
        if not all(isinstance(n, str) and n.strip() for n in names_raw):
            raise _err(src, "names", "every name must be a non-empty string")
        dup = sorted({n for n in names_raw if names_raw.count(n) > 1})
        if dup:
            raise _err(src, "names", f"duplicate names {dup}")
        names = tuple(names_raw)

    mob_raw = raw.get("mobility")
    if mob_raw is None:
        if cats is None:
            cats = _json_categories(ref_json, src, f"{ref_split}.annotations")
        by_name = {str(c["name"]): c.get("mobility") for c in cats}
        priors = [by_name.get(n) for n in names]
        mobility: tuple[float, ...] = ()
        if all(isinstance(p, (int, float)) and not isinstance(p, bool) for p in priors):
            mobility = tuple(_prior(p, src, f"{ref_split}.annotations mobility") for p in priors)
    elif isinstance(mob_raw, list):
        if len(mob_raw) != len(names):
            raise _err(
                src, "mobility", f"has {len(mob_raw)} values but there are {len(names)} names"
            )
        mobility = tuple(_prior(v, src, f"mobility[{i}]") for i, v in enumerate(mob_raw))
    elif isinstance(mob_raw, Mapping):
        extra = sorted(set(mob_raw) - set(names))
        missing = [n for n in names if n not in mob_raw]
        if extra or missing:
            raise _err(src, "mobility", f"names not in 'names': {extra}; missing: {missing}")
        mobility = tuple(_prior(mob_raw[n], src, f"mobility.{n}") for n in names)
    else:
        raise _err(src, "mobility", "expected a list (same order as names) or {name: prior}")

    return DataConfig(
        root=root,
        train=splits.get("train"),
        val=splits.get("val"),
        names=names,
        mobility=mobility,
        source=src,
    )
