"""COCO instance-segmentation json from rendered frames (compressed RLE of the visible part)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pycocotools import mask as mask_utils

from slimseg.data.synth.categories import coco_categories
from slimseg.data.synth.scene import Frame
from slimseg.utils.atomic import write_json

MIN_AREA = 16  # instances with fewer visible pixels are left out of the json


def encode_mask(mask: np.ndarray) -> dict:
    """``bool``/``uint8 [H, W]`` mask -> COCO compressed RLE with ``counts`` as ``str``."""
    rle = mask_utils.encode(np.asfortranarray(mask.astype(np.uint8)))
    rle["counts"] = rle["counts"].decode("ascii")
    return rle


def frame_annotations(
    frame: Frame, image_id: int, min_area: int = MIN_AREA, extra: bool = False
) -> list[dict]:
    """One COCO annotation per placement with at least ``min_area`` visible pixels.

    ``bbox`` is ``[x, y, w, h]`` of the visible mask (pycocotools convention), ``area`` its
    pixel count, ``depth_m`` the instance's depth. ``id`` is left for :class:`CocoBuilder`.
    With ``extra``: ``track_id`` and ``moving`` (sequence mode).
    """
    out = []
    for i, p in enumerate(frame.placements):
        m = frame.mask(i)
        area = int(np.count_nonzero(m))
        if area < min_area:
            continue
        rle = encode_mask(m)
        ann = {
            "image_id": image_id,
            "category_id": p.category_id,
            "segmentation": rle,
            "area": area,
            "bbox": [float(v) for v in mask_utils.toBbox(rle)],
            "iscrowd": 0,
            "depth_m": round(float(p.depth), 4),
        }
        if extra:
            ann |= {"track_id": p.track_id, "moving": p.moving}
        out.append(ann)
    return out


class CocoBuilder:
    """Collects images and annotations; ``write`` dumps the json (ids assigned in order)."""

    def __init__(self, description: str) -> None:
        self.info = {"description": description, "version": "1.0"}
        self.images: list[dict] = []
        self.annotations: list[dict] = []

    def add(self, image: dict, annotations: list[dict]) -> None:
        """Add one ``image`` entry (``id``, ``file_name``, ``width``, ``height``, ...) and its
        annotations (their ``id`` is assigned here, 1-based)."""
        self.images.append(image)
        for ann in annotations:
            self.annotations.append({"id": len(self.annotations) + 1, **ann})

    def to_dict(self) -> dict:
        """The COCO json object (``info``, ``images``, ``annotations``, ``categories``)."""
        return {
            "info": self.info,
            "images": self.images,
            "annotations": self.annotations,
            "categories": coco_categories(),
        }

    def write(self, path: Path) -> None:
        """Write the json atomically to ``path``."""
        write_json(path, self.to_dict())
