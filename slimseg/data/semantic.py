"""Semantic class maps from instances: training targets and YOLO predictions alike.

A class map is ``[H, W]`` with ``0`` = background and ``k + 1`` = dataset class ``k``;
:data:`IGNORE_INDEX` marks pixels no metric or loss looks at (the letterbox padding of
validation images).
"""

from __future__ import annotations

import numpy as np

from slimseg.ops.letterbox import LetterboxParams
from slimseg.ops.semantic import IGNORE_INDEX


def semantic_target(
    masks: np.ndarray, classes: np.ndarray, order: np.ndarray | None = None
) -> np.ndarray:
    """Instances → ``int64 [H, W]`` class map (0 = background, class id + 1).

    ``masks``: ``[N, H, W]`` (nonzero = instance pixel); ``classes``: ``[N]`` ids ``0..K-1``.
    Instances are painted in ``order`` (default: their index order), so where two overlap
    the later one wins.
    """
    if masks.ndim != 3 or len(masks) != len(classes):
        raise ValueError(
            f"expected masks [N, H, W] and classes [N], got {masks.shape}, {np.shape(classes)}"
        )
    out = np.zeros(masks.shape[1:], np.int64)
    for i in range(len(masks)) if order is None else order:
        out[masks[i].astype(bool)] = int(classes[i]) + 1
    return out


def instances_to_semantic(masks: np.ndarray, classes: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """Instance predictions → ``int64 [H, W]`` class map, painted by ascending confidence
    (where masks overlap, the most confident detection's class wins)."""
    order = np.argsort(np.asarray(scores, np.float64), kind="stable")
    return semantic_target(masks, classes, order)


def ignore_padding(target: np.ndarray, p: LetterboxParams) -> np.ndarray:
    """Set the letterbox padding of an input-sized class map to :data:`IGNORE_INDEX`."""
    keep = np.zeros(target.shape, bool)
    keep[p.top : p.top + p.new_h, p.left : p.left + p.new_w] = True
    target = target.copy()
    target[~keep] = IGNORE_INDEX
    return target
