"""Plain data types for the detections of one frame: the leaf every stage imports.

Each type's docstring opens with its coordinate frame. Which type at which stage:
``docs/conventions.md`` ("Detections of one frame").

- :class:`Detections`: after NMS, **network-input pixels** (torch tensors, raw mask
  coefficients): what ``slimseg.ops.nms`` returns.
- :class:`FrameDetections`: **source-frame pixels** (numpy; masks dense or as COCO RLEs):
  what validation scores.
- :class:`Prediction`: **source-frame pixels**, detections with class names, mobility priors
  and timings (or a semantic class map): what the predictor returns; the per-frame masking
  chain (``slimseg.dynamic``) takes it in as :class:`slimseg.objects.Objects`.

At import this module loads nothing of slimseg and nothing but numpy and the standard
library, so any layer may use it and the core install (no torch) imports it:
:class:`Detections` names torch only in its annotations (its tensors are made by its
producer, ``slimseg.ops.nms``), and the RLE conversions import pycocotools when called.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import torch


@dataclass(eq=False)
class Detections:
    """Network-input pixels. Detections of one image after NMS, sorted by decreasing score.

    ``boxes``: ``float [N, 4]`` xyxy in network-input pixels; ``scores``: ``float [N]``;
    ``classes``: ``int64 [N]`` contiguous class ids; ``coeffs``: ``float [N, nm]`` raw mask
    coefficients (``[N, 0]`` for detection-only models).
    """

    boxes: torch.Tensor
    scores: torch.Tensor
    classes: torch.Tensor
    coeffs: torch.Tensor

    def __len__(self) -> int:
        return int(self.scores.shape[0])


@dataclass(eq=False)
class FrameDetections:
    """Source-frame pixels. Detections of one image, sorted by decreasing score.

    ``boxes``: ``float32 [N, 4]`` xyxy, clipped to the frame; ``scores``: ``float32 [N]``;
    ``classes``: ``int64 [N]`` contiguous class ids; ``masks``: ``bool [N, h, w]`` or
    ``None``; ``rles``: ``N`` COCO RLE dicts (``size [h, w]``, ``counts`` str) or ``None``;
    ``image_hw``: ``(h, w)``. Detection-only results have neither masks nor RLEs. An RLE
    entry is ``None`` for a detection whose mask was not assembled (validation skips those
    beyond :data:`COCO_MAX_DETS` of their class: COCO never looks at them).
    """

    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray
    image_hw: tuple[int, int]
    masks: np.ndarray | None = None
    rles: list[dict | None] | None = None

    def __len__(self) -> int:
        return len(self.scores)

    @property
    def has_masks(self) -> bool:
        return self.masks is not None or self.rles is not None

    def mask_rles(self) -> list[dict | None]:
        """The masks as COCO RLEs (encoded from ``masks`` if only those are stored)."""
        if self.rles is not None:
            return self.rles
        if self.masks is None:
            raise ValueError("these detections have no masks (detection-only model)")
        return encode_rle(self.masks)

    def dense_masks(self) -> np.ndarray:
        """The masks as ``bool [N, h, w]`` (decoded from ``rles`` if only those are stored)."""
        if self.masks is not None:
            return self.masks
        if self.rles is None:
            raise ValueError("these detections have no masks (detection-only model)")
        return decode_rle(self.rles, self.image_hw)

    @classmethod
    def empty(cls, image_hw: tuple[int, int], with_masks: bool = False) -> FrameDetections:
        """No detection (masks ``bool [0, h, w]`` if ``with_masks``)."""
        h, w = image_hw
        return cls(
            boxes=np.zeros((0, 4), np.float32),
            scores=np.zeros(0, np.float32),
            classes=np.zeros(0, np.int64),
            image_hw=(h, w),
            masks=np.zeros((0, h, w), bool) if with_masks else None,
        )


def encode_rle(masks: np.ndarray) -> list[dict]:
    """``bool/uint8 [N, h, w]`` → ``N`` COCO RLE dicts (``counts`` as str, json-ready)."""
    if len(masks) == 0:
        return []
    from pycocotools import mask as mask_utils

    # [N, w, h] C order is [h, w, N] Fortran order: one transpose copy per mask.
    fortran = np.ascontiguousarray(np.transpose(masks, (0, 2, 1)), dtype=np.uint8).T
    rles = mask_utils.encode(fortran)
    for r in rles:
        r["counts"] = r["counts"].decode("ascii")
    return rles


def decode_rle(rles: Sequence[dict], image_hw: tuple[int, int]) -> np.ndarray:
    """``N`` COCO RLE dicts → ``bool [N, h, w]``."""
    if len(rles) == 0:
        return np.zeros((0, *image_hw), bool)
    from pycocotools import mask as mask_utils

    with warnings.catch_warnings():
        # pycocotools' Cython array lacks numpy 2's ``copy`` keyword: harmless, silenced here.
        warnings.filterwarnings("ignore", "__array__ implementation", DeprecationWarning)
        return np.transpose(mask_utils.decode(list(rles)), (2, 0, 1)).astype(bool)


@dataclass(eq=False)
class Prediction:
    """Source-frame pixels. Detections of one frame, sorted by decreasing score.

    ``boxes``: ``float32 [N, 4]`` xyxy, clipped to the frame; ``scores``: ``float32 [N]``;
    ``classes``: ``int64 [N]``; ``names`` and ``mobility``: the class name and mobility prior
    of each detection; ``masks``: ``bool [N, h, w]`` (``None`` for detection-only models);
    ``image_hw``: ``(h, w)``; ``timings``: milliseconds spent in ``preprocess``,
    ``inference`` and ``postprocess``.

    Semantic models (MSNET) have no detections (empty ``boxes``/``scores``/``classes``,
    ``masks`` ``None``); their output is ``class_map``: ``uint8 [h, w]`` on the source frame,
    ``0`` = background, ``k + 1`` = class ``k`` (``int32`` if a model had over 254 classes).
    It is ``None`` for detectors and instance segmenters. ``class_names``: the model's class
    names (``class_names[k]`` is value ``k + 1`` of ``class_map``; empty for the others).
    """

    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray
    names: list[str]
    mobility: list[float]
    masks: np.ndarray | None
    image_hw: tuple[int, int]
    timings: dict[str, float] = field(default_factory=dict)
    class_map: np.ndarray | None = None
    class_names: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.scores)

    def detections(self) -> list[dict[str, Any]]:
        """JSON-ready detections: ``box`` xyxy, ``class``, ``name``, ``score``, ``mobility``."""
        return [
            {
                "box": [round(float(v), 2) for v in box],
                "class": int(cls),
                "name": name,
                "score": round(float(score), 5),
                "mobility": float(mob),
            }
            for box, cls, name, score, mob in zip(
                self.boxes, self.classes, self.names, self.scores, self.mobility, strict=True
            )
        ]
