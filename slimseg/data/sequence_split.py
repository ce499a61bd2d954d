"""Splits read from annotated TUM-layout sequences: one COCO json over many folders.

A ``data.yaml`` split may name sequence folders (``train: {sequences: [DIR, ...], stride:
N}``, see :mod:`slimseg.data.config`), each holding the frames and an ``annotations.json``
(COCO instances, ``file_name`` relative to the folder: what ``slimseg data synth
--sequences`` writes and what a labelling tool's COCO export of the frames gives). Neighbouring
frames of a sequence are near-duplicates, so the split takes every ``stride``-th frame of each
sequence, in file-name order (TUM timestamps sort in time order).

:func:`merge_split` turns the parts of such a split (the sequences, plus the split's own
``images``/``annotations`` when it mixes still images in) into one COCO dict whose
``file_name`` values are relative to the parts' common folder, with image and annotation ids
renumbered from 1 (ids repeat across sequences). Every part must list the same categories
(id and name). A missing ``annotations.json`` or a listed frame whose file is absent is a
:class:`~slimseg.errors.SlimsegError` naming the file; everything else a COCO json can get
wrong is left to the index (counted, as for any split: ``slimseg data check``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from slimseg.data.coco_index import load_coco_json
from slimseg.errors import SlimsegError

#: The COCO instances file of a sequence folder (its ``file_name`` values are relative to it).
SEQUENCE_ANNOTATIONS = "annotations.json"


@dataclass(frozen=True)
class SplitPart:
    """One source of a split: ``images`` (the folder ``file_name`` is relative to), its COCO
    json and the frame stride (1: every image)."""

    images: Path
    annotations: Path
    stride: int = 1


def _frame_key(image: object) -> str:
    return image.get("file_name", "") if isinstance(image, dict) else ""


def _categories(data: dict) -> list[tuple[int, str]]:
    return sorted((int(c["id"]), str(c["name"])) for c in data["categories"])


def merge_split(parts: list[SplitPart], where: str) -> tuple[Path, dict]:
    """``(root, coco)``: one COCO dict over ``parts``, ``file_name`` relative to ``root``.

    ``where`` names the split in errors (e.g. ``"data.yaml: 'train.sequences'"``). Images of
    a part with stride ``s`` are sorted by file name and every ``s``-th is kept (the first
    included); annotations of dropped frames are dropped with them, annotations of unknown
    images are kept with an image id no image has (the index counts them as orphans).
    """
    if not parts:
        raise ValueError("merge_split needs at least one part")
    root = Path(os.path.commonpath([str(p.images) for p in parts]))
    merged: dict = {"info": {"description": f"slimseg merged split ({where})"}}
    images: list = []
    annotations: list = []
    first: tuple[Path, list[tuple[int, str]]] | None = None
    orphan_id = -1
    for part in parts:
        if not part.annotations.is_file():
            raise SlimsegError(
                f"{where}: {part.annotations} not found (a sequence needs its COCO instances "
                f"as {SEQUENCE_ANNOTATIONS} beside rgb/, file_name relative to its folder)"
            )
        data = load_coco_json(part.annotations)
        cats = _categories(data)
        if first is None:
            first = (part.annotations, cats)
            merged["categories"] = data["categories"]
        elif cats != first[1]:
            raise SlimsegError(
                f"{part.annotations}: categories {cats} differ from {first[0]}'s {first[1]}; "
                "every part of a split needs the same category ids and names"
            )
        listed = sorted(data["images"], key=_frame_key)
        kept = listed[:: part.stride]
        new_ids: dict[int, int] = {}
        for im in kept:
            if not isinstance(im, dict) or not isinstance(im.get("file_name"), str):
                images.append(im)  # malformed: the index reports it
                continue
            path = part.images / im["file_name"]
            if not path.is_file():
                raise SlimsegError(
                    f"{part.annotations}: frame '{im['file_name']}' is listed but {path} does "
                    "not exist; remove it from the json or restore the file"
                )
            new_ids[id(im)] = len(images) + 1
            images.append(
                dict(
                    im,
                    id=len(images) + 1,
                    file_name=os.path.relpath(path, root),
                    source=str(part.images),
                )
            )
        # old id -> new id, None for a frame the stride skipped
        by_old = {im.get("id"): new_ids.get(id(im)) for im in listed if isinstance(im, dict)}
        for ann in data["annotations"]:
            if not isinstance(ann, dict):
                annotations.append(ann)
                continue
            old = ann.get("image_id")
            if old in by_old and by_old[old] is None:
                continue  # a frame the stride skipped
            if old in by_old:
                new = by_old[old]
            else:
                new, orphan_id = orphan_id, orphan_id - 1
            annotations.append(dict(ann, id=len(annotations) + 1, image_id=new))
    merged["images"], merged["annotations"] = images, annotations
    return root, merged
