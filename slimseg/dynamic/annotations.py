"""Ground-truth instances of a synthetic sequence as detections (detector-independent tests).

``slimseg data synth --sequences`` writes ``annotations.json`` (COCO, one image per colour
frame, categories with a ``mobility`` prior, annotations with ``track_id`` and ``moving``).
:class:`AnnotationInstances` serves them in the shape of a model's ``Prediction`` so the masking
modes, the epipolar check and restoration can be evaluated without a detector's errors.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from pycocotools import mask as mask_utils

from slimseg.data.coco_rle import segm_to_rle
from slimseg.detections import Prediction
from slimseg.errors import SlimsegError


class AnnotationInstances:
    """Instances of ``<sequence>/annotations.json`` keyed by colour timestamp.

    ``names`` / ``mobility``: per class (class index = COCO category id - 1, as the synth
    categories are numbered 1..K). :meth:`for_stamp` gives one frame's ``Prediction`` (score 1)
    and :meth:`moving` the ``moving`` flag of each of its instances.
    """

    def __init__(self, sequence: str | Path) -> None:
        path = Path(sequence) / "annotations.json"
        if not path.is_file():
            raise SlimsegError(
                f"{path} not found: ground-truth instances need a synthetic sequence "
                "('slimseg data synth --sequences N')"
            )
        try:
            coco = json.loads(path.read_text(encoding="utf-8"))
            cats = sorted(coco["categories"], key=lambda c: c["id"])
            images = {im["id"]: im for im in coco["images"]}
            anns = coco["annotations"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise SlimsegError(f"cannot read {path}: {e}") from None
        if [c["id"] for c in cats] != list(range(1, len(cats) + 1)):
            raise SlimsegError(f"{path}: category ids must be 1..K")
        self.path = path
        self.names = [str(c["name"]) for c in cats]
        self.mobility = [float(c.get("mobility", 1.0)) for c in cats]
        self._by_stamp: dict[str, tuple[dict, list[dict]]] = {}
        for im in images.values():
            self._by_stamp[f"{float(im['timestamp']):.6f}"] = (im, [])
        for a in anns:
            im = images.get(a["image_id"])
            if im is not None:
                self._by_stamp[f"{float(im['timestamp']):.6f}"][1].append(a)

    def _frame(self, stamp: float) -> tuple[dict, list[dict]]:
        key = f"{float(stamp):.6f}"
        if key not in self._by_stamp:
            raise SlimsegError(f"{self.path}: no image with timestamp {key}")
        return self._by_stamp[key]

    def for_stamp(self, stamp: float) -> Prediction:
        """The frame's instances: boxes xyxy, classes, ``masks bool [N, H, W]``."""
        im, anns = self._frame(stamp)
        h, w = int(im["height"]), int(im["width"])
        masks = np.zeros((len(anns), h, w), bool)
        boxes = np.zeros((len(anns), 4), np.float32)
        classes = np.array([a["category_id"] - 1 for a in anns], np.int64)
        for k, a in enumerate(anns):
            masks[k] = mask_utils.decode(segm_to_rle(a["segmentation"], h, w)) > 0
            x, y, bw, bh = a["bbox"]
            boxes[k] = (x, y, x + bw, y + bh)
        return Prediction(
            boxes=boxes,
            scores=np.ones(len(anns), np.float32),
            classes=classes,
            names=[self.names[c] for c in classes],
            mobility=[self.mobility[c] for c in classes],
            masks=masks,
            image_hw=(h, w),
        )

    def moving(self, stamp: float) -> np.ndarray:
        """``bool [N]``: the ground-truth ``moving`` flag of each instance of the frame."""
        return np.array([bool(a.get("moving", False)) for a in self._frame(stamp)[1]], bool)
