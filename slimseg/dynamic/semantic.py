"""Semantic class maps (MSNET) as instance regions, so every masking mode accepts them.

A semantic segmenter labels pixels, not objects. The masking logic works per object (Eq. 1
thresholds a mask's mobility, Eq. 4 compares a mask with its box, the epipolar check votes per
object), so each class's connected components (8-connectivity) become the objects: a mask,
its bounding box and the class. Components under ``min_area`` pixels are label noise and are
dropped; the mobility of each object is its class prior, as for the instance models.
"""

from __future__ import annotations

import cv2
import numpy as np

from slimseg.detections import Prediction
from slimseg.objects import Objects


def class_map_to_instances(
    class_map: np.ndarray, min_area: int = 32
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``class_map [H, W]`` (0 = background, ``k + 1`` = class ``k``) → ``boxes float32 [M, 4]``
    xyxy px (exclusive right/bottom), ``classes int64 [M]``, ``masks bool [M, H, W]``."""
    h, w = class_map.shape
    boxes, classes, masks = [], [], []
    for value in np.unique(class_map):
        if value == 0:
            continue
        count, labels, stats, _ = cv2.connectedComponentsWithStats(
            (class_map == value).astype(np.uint8), connectivity=8
        )
        for j in range(1, count):  # label 0: everything that is not this class
            x, y, bw, bh, area = stats[j]
            if area < min_area:
                continue
            boxes.append([x, y, x + bw, y + bh])
            classes.append(int(value) - 1)
            masks.append(labels == j)
    if not boxes:
        return np.zeros((0, 4), np.float32), np.zeros(0, np.int64), np.zeros((0, h, w), bool)
    return np.array(boxes, np.float32), np.array(classes, np.int64), np.stack(masks)


def objects_of(prediction: Prediction, hw: tuple[int, int]) -> Objects:
    """A model result as the chain's :class:`~slimseg.objects.Objects` of an ``hw`` frame: its
    own instances, or the components of a semantic ``class_map`` (each scoring 1); ``masks``
    None for detection-only models. The chain's one way in from a :class:`Prediction`."""
    if prediction.class_map is not None:
        boxes, classes, masks = class_map_to_instances(prediction.class_map)
        return Objects(boxes, np.ones(len(boxes), np.float32), classes, masks, hw)
    p = prediction
    return Objects(p.boxes, p.scores, p.classes, p.masks, hw)
