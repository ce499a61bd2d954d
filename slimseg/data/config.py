"""Dataset configs (``data.yaml``): where a COCO-format dataset lives and what its classes are.

Schema::

    path: ROOT            # optional. Relative paths below resolve against it; itself relative
                          # to the yaml's folder ('~' expanded). Default: the yaml's folder.
    train:                # optional if val is given
      images: DIR         # folder that file_name in the json is relative to
      annotations: FILE   # COCO instances json
      depth: DIR          # optional: uint16 PNG depth per image, same relative path, .png
      sequences: [DIR, ...]  # optional: annotated TUM-layout sequences (annotations.json
                          # beside rgb/), alone or besides images/annotations
                          # (slimseg.data.sequence_split)
      stride: N           # optional, with sequences: every N-th frame of each (default 1)
    val:                  # optional if train is given; same keys as train
      images: DIR
      annotations: FILE
    names: [a, b, ...]    # optional. Class i = names[i], matched *by name* to the json
                          # categories. Default: the json categories sorted by id.
    mobility: [1.0, ...]  # optional. Mobility prior in [0, 1] per class, same order as names,
                          # or a mapping {name: prior} covering every class. Default: the
                          # json categories' 'mobility' fields (written by
                          # 'slimseg data coco-subset'), else none (empty tuple).
    sequences: [DIR, ...] # optional. TUM RGB-D layout folders (rgb.txt, depth.txt, rgb/,
                          # depth/; what 'slimseg dynamic --sequence' and 'slimseg slam-eval
                          # --sequence' read), named by their folder name, or a mapping
                          # {name: DIR}. Written by 'slimseg data synth --sequences N'.

Every path below ``path`` must lie inside the root (relative without climbing out with ``..``,
or absolute inside it; ``slimseg --allow-outside-root`` lifts this,
:func:`slimseg.utils.outputs.inside_root`).

A yaml needs a train or val split, or sequences; without a split, ``names`` is required (no
json to take them from) and ``split()`` says the file has none. Default names and mobility come
from the val json (usually the smaller one), else train. Every problem (unknown key, missing
file or folder, bad names, mobility or sequences) raises :class:`~slimseg.errors.SlimsegError`
naming the yaml and the field.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from slimseg.data.sequence_split import SEQUENCE_ANNOTATIONS, SplitPart
from slimseg.errors import SlimsegError
from slimseg.utils.input_files import check_regular
from slimseg.utils.outputs import inside_root
from slimseg.utils.shipped import resolve_config
from slimseg.utils.yaml_io import read_yaml

_TOP_KEYS = {"path", "train", "val", "names", "mobility", "sequences"}
_SPLIT_KEYS = {"images", "annotations", "depth", "sequences", "stride"}
SPLITS = ("train", "val")
TUM_LISTS = ("rgb.txt", "depth.txt")  # what makes a folder a TUM-layout sequence


@dataclass(frozen=True)
class SplitConfig:
    """One split (absolute paths): an images folder with its COCO json (and optional depth
    folder), annotated sequence folders taken every ``stride``-th frame, or both. At least one
    of ``images`` (with ``annotations``) and ``sequences`` is set."""

    images: Path | None = None
    annotations: Path | None = None
    depth: Path | None = None
    sequences: tuple[Path, ...] = ()
    stride: int = 1

    @property
    def parts(self) -> list[SplitPart]:
        """The split's sources for :func:`~slimseg.data.sequence_split.merge_split`."""
        out = []
        if self.images is not None and self.annotations is not None:
            out.append(SplitPart(self.images, self.annotations))
        out += [SplitPart(f, f / SEQUENCE_ANNOTATIONS, self.stride) for f in self.sequences]
        return out

    @property
    def reference_json(self) -> Path:
        """The json whose categories give default names: the split's own, else its first
        sequence's."""
        return self.annotations if self.annotations is not None else self.parts[0].annotations


@dataclass(frozen=True)
class DataConfig:
    """A loaded ``data.yaml``: resolved paths, class names and mobility priors.

    ``mobility`` is empty when neither the yaml nor the json gives priors; otherwise it has
    one float in ``[0, 1]`` per name. ``sequences``: TUM-layout sequence folders by name
    (absolute paths, yaml order; empty when the yaml lists none).
    """

    root: Path
    train: SplitConfig | None
    val: SplitConfig | None
    names: tuple[str, ...]
    mobility: tuple[float, ...]
    source: Path
    sequences: dict[str, Path] = field(default_factory=dict)

    @property
    def num_classes(self) -> int:
        return len(self.names)

    def split(self, name: str) -> SplitConfig:
        """The ``train`` or ``val`` split; SlimsegError if the yaml does not define it."""
        if name not in SPLITS:
            raise SlimsegError(f"unknown split '{name}' (use one of {', '.join(SPLITS)})")
        s = getattr(self, name)
        if s is None:
            if self.train is None and self.val is None:
                raise SlimsegError(
                    f"{self.source}: no '{name}' split (it lists only the TUM sequences "
                    f"{', '.join(self.sequences)}); add '{name}: {{images: DIR, annotations: "
                    "FILE}' to it, or regenerate a synthetic set with --train N --val N"
                )
            raise SlimsegError(f"{self.source}: no '{name}' split; add '{name}:' to the yaml")
        return s


def _err(src: Path, field: str, msg: str) -> SlimsegError:
    return SlimsegError(f"{src}: '{field}': {msg}")


def _resolve(base: Path, value: Any, src: Path, field: str, confined: bool = True) -> Path:
    """``value`` against ``base``, resolved; ``confined`` (every field but ``path``, which
    names the root): refused when it lies outside ``base`` (:func:`inside_root`)."""
    if not isinstance(value, str) or not value.strip():
        raise _err(src, field, f"expected a path string, got {value!r}")
    if confined:
        return inside_root(base, value, f"{src}: '{field}'").resolve()
    p = Path(value).expanduser()
    return (p if p.is_absolute() else base / p).resolve()


def _split(raw: Any, root: Path, src: Path, name: str) -> SplitConfig:
    if not isinstance(raw, Mapping):
        raise _err(src, name, "expected a mapping with 'images' and 'annotations' or 'sequences'")
    unknown = set(raw) - _SPLIT_KEYS
    if unknown:
        raise _err(src, name, f"unknown keys {sorted(unknown)} (allowed: {sorted(_SPLIT_KEYS)})")
    has_seq = raw.get("sequences") is not None
    images = ann = depth = None
    if not has_seq or "images" in raw or "annotations" in raw:
        for key in ("images", "annotations"):
            if key not in raw:
                hint = "" if has_seq else " (or name annotated TUM sequences with 'sequences')"
                raise _err(src, f"{name}.{key}", f"missing{hint}")
        images = _resolve(root, raw["images"], src, f"{name}.images")
        if not images.is_dir():
            raise _err(src, f"{name}.images", f"folder {images} not found")
        ann = _resolve(root, raw["annotations"], src, f"{name}.annotations")
        if not ann.is_file():
            raise _err(src, f"{name}.annotations", f"file {ann} not found")
    if raw.get("depth") is not None:
        if images is None or has_seq:
            raise _err(
                src, f"{name}.depth", "goes with an images-only split (sequences keep their own)"
            )
        depth = _resolve(root, raw["depth"], src, f"{name}.depth")
        if not depth.is_dir():
            raise _err(src, f"{name}.depth", f"folder {depth} not found")
    stride = raw.get("stride", 1)
    if "stride" in raw and not has_seq:
        raise _err(src, f"{name}.stride", "applies to 'sequences' only")
    if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
        raise _err(src, f"{name}.stride", f"expected a whole number of frames >= 1, got {stride!r}")
    sequences: tuple[Path, ...] = ()
    if has_seq:
        folders = _sequences(raw["sequences"], root, src, f"{name}.sequences", lists=False)
        for fld, folder in folders.items():
            if not (folder / SEQUENCE_ANNOTATIONS).is_file():
                raise _err(
                    src,
                    fld,
                    f"{folder} has no {SEQUENCE_ANNOTATIONS} (the COCO instances of its frames, "
                    "file_name relative to the folder; 'slimseg data synth --sequences' writes "
                    "one, a labelling tool's COCO export gives one)",
                )
        sequences = tuple(folders.values())
    return SplitConfig(images, ann, depth, sequences, stride)


def _sequences(
    raw: Any, root: Path, src: Path, key: str = "sequences", lists: bool = True
) -> dict[str, Path]:
    """``sequences`` (or a split's ``key``): a list of folders (named by folder name) or
    ``{name: folder}``; every folder must exist and, with ``lists``, hold the TUM lists.
    A split's sequences (``lists=False``) are returned by field (``train.sequences[0]``), so
    two folders of one name may both train."""
    items: list[tuple[str, Path, str]] = []  # (name, folder, field)
    if isinstance(raw, list) and raw:
        for i, v in enumerate(raw):
            folder = _resolve(root, v, src, f"{key}[{i}]")
            items.append((folder.name, folder, f"{key}[{i}]"))
    elif isinstance(raw, Mapping) and raw:
        for k, v in raw.items():
            if not isinstance(k, str) or not k.strip():
                raise _err(src, key, f"sequence names must be non-empty strings, got {k!r}")
            items.append((k, _resolve(root, v, src, f"{key}.{k}"), f"{key}.{k}"))
    else:
        raise _err(src, key, "expected a non-empty list of sequence folders or {name: folder}")
    out: dict[str, Path] = {}
    for name, folder, fld in items:
        if lists and name in out:
            raise _err(
                src, fld, f"a second sequence named '{name}'; use a mapping {{name: folder}}"
            )
        if not folder.is_dir():
            raise _err(src, fld, f"folder {folder} not found")
        missing = [f for f in TUM_LISTS if not (folder / f).is_file()]
        if lists and missing:
            raise _err(src, fld, f"{folder} is not a TUM-layout sequence (no {', '.join(missing)})")
        out[name if lists else fld] = folder
    return out


def _json_categories(path: Path, src: Path, field: str) -> list[dict]:
    try:
        check_regular(path, "annotation file")  # a FIFO would block the read
        with open(path, encoding="utf-8") as f:
            cats = json.load(f).get("categories")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError) as exc:
        raise _err(src, field, f"cannot read categories from {path} ({exc})") from None
    except RecursionError:
        raise _err(src, field, f"cannot read categories from {path} (nested too deeply)") from None
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
        root = _resolve(src.parent, raw["path"], src, "path", confined=False)
        if not root.is_dir():
            raise _err(src, "path", f"folder {root} not found")
    splits = {s: _split(raw[s], root, src, s) for s in SPLITS if raw.get(s) is not None}
    sequences = _sequences(raw["sequences"], root, src) if raw.get("sequences") is not None else {}
    if not splits and not sequences:
        raise SlimsegError(f"{src}: needs a 'train' and/or 'val' split (or 'sequences')")
    ref_split = "val" if "val" in splits else "train"
    ref_json = splits[ref_split].reference_json if splits else None

    cats: list[dict] | None = None
    names_raw = raw.get("names")
    if names_raw is None:
        if ref_json is None:
            raise _err(src, "names", "required when there is no train/val json to read them from")
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
    if mob_raw is None and ref_json is None:
        mobility: tuple[float, ...] = ()
    elif mob_raw is None:
        if cats is None:
            cats = _json_categories(ref_json, src, f"{ref_split}.annotations")
        by_name = {str(c["name"]): c.get("mobility") for c in cats}
        priors = [by_name.get(n) for n in names]
        mobility = ()
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
        sequences=sequences,
    )
