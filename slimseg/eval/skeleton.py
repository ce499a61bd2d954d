"""Skeleton recall of person masks: how much of each ground-truth person's medial line (and of
its thin parts: limbs) a matched detection covers.

* **Skeleton**: Zhang–Suen thinning (two sub-iterations per pass, repeated until nothing
  changes), 8-connected, pixels outside the image = background. A 3-pixel-wide bar of
  length ``L`` thins to its middle row, ``L − 3`` pixels long.
* **Local width** of a mask pixel: ``2 × dt``, ``dt`` the exact Euclidean distance from its
  centre to the nearest background pixel centre (outside the image = background); a skeleton
  pixel is *thin* when its width is ``<= THIN_WIDTH`` (limbs up to 6 pixels across).
* **Matching**: detections in decreasing score (stable) each take the unmatched ground truth
  with the highest mask IoU, if that IoU is ``>= MATCH_IOU`` (COCO's greedy rule at one
  threshold); an unmatched ground truth covers nothing.

See docs/mask_quality.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: A skeleton pixel whose local mask width (``2 × distance transform``) is at most this
#: many pixels belongs to a thin part.
THIN_WIDTH = 6.0
#: Mask IoU a detection needs to be matched to a ground-truth person.
MATCH_IOU = 0.5


def _thinning_pass(img: np.ndarray, second: bool) -> bool:
    """One Zhang–Suen sub-iteration on the zero-bordered ``uint8 [H + 2, W + 2]`` image, in
    place; True when it removed a pixel."""
    c = img[1:-1, 1:-1]
    # P2..P9: N, NE, E, SE, S, SW, W, NW
    p = [
        img[:-2, 1:-1],
        img[:-2, 2:],
        img[1:-1, 2:],
        img[2:, 2:],
        img[2:, 1:-1],
        img[2:, :-2],
        img[1:-1, :-2],
        img[:-2, :-2],
    ]
    count = sum(q.astype(np.int8) for q in p)
    transitions = sum(((p[k] == 0) & (p[(k + 1) % 8] == 1)).astype(np.int8) for k in range(8))
    n, e, s, w = p[0], p[2], p[4], p[6]
    # first sub-iteration: N·E·S = 0 and E·S·W = 0; second: N·E·W = 0 and N·S·W = 0
    blocked = ((n & e & w) | (n & s & w)) if second else ((n & e & s) | (e & s & w))
    remove = (c == 1) & (count >= 2) & (count <= 6) & (transitions == 1) & (blocked == 0)
    if not remove.any():
        return False
    c[remove] = 0
    return True


def skeletonize(mask: np.ndarray) -> np.ndarray:
    """``bool [H, W]`` → ``bool [H, W]``: the Zhang–Suen skeleton of the mask (see the module
    docstring); computed on the mask's bounding box only."""
    if mask.ndim != 2:
        raise ValueError(f"expected a mask [H, W], got shape {mask.shape}")
    out = np.zeros(mask.shape, bool)
    rows, cols = np.nonzero(mask.any(1))[0], np.nonzero(mask.any(0))[0]
    if rows.size == 0:
        return out
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    img = np.pad(mask[r0:r1, c0:c1].astype(np.uint8), 1)
    while _thinning_pass(img, second=False) | _thinning_pass(img, second=True):
        pass
    out[r0:r1, c0:c1] = img[1:-1, 1:-1].astype(bool)
    return out


def local_width(mask: np.ndarray) -> np.ndarray:
    """``bool [H, W]`` → ``float32 [H, W]``: ``2 ×`` the Euclidean distance of each mask pixel
    to the nearest background pixel (outside the image = background); 0 off the mask."""
    if mask.ndim != 2:
        raise ValueError(f"expected a mask [H, W], got shape {mask.shape}")
    padded = np.pad(mask.astype(np.uint8), 1)
    dist = cv2.distanceTransform(padded, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return 2.0 * dist[1:-1, 1:-1]


def greedy_match(ious: np.ndarray, scores: np.ndarray, threshold: float = MATCH_IOU) -> np.ndarray:
    """COCO-style one-to-one matching at one IoU threshold.

    ``ious``: ``float [D, G]`` mask IoU of each detection with each ground truth; ``scores``:
    ``float [D]``. Returns ``int64 [G]``: the detection matched to each ground truth, -1 if
    none. Detections go in decreasing score (stable); each takes the unmatched ground truth
    of highest IoU, when that IoU is ``>= threshold``.
    """
    d, g = ious.shape
    if len(scores) != d:
        raise ValueError(f"{len(scores)} scores for {d} detections")
    matched = np.full(g, -1, np.int64)
    if d == 0 or g == 0:
        return matched
    free = np.ones(g, bool)
    for i in np.argsort(-np.asarray(scores, float), kind="stable"):
        row = np.where(free, ious[i], -1.0)
        j = int(row.argmax())
        if row[j] >= threshold:
            matched[j] = i
            free[j] = False
    return matched


@dataclass
class SkeletonTally:
    """Skeleton pixels of ground-truth instances and how many a matched detection covers."""

    instances: int = 0
    matched: int = 0
    pixels: int = 0
    covered: int = 0
    thin_pixels: int = 0
    thin_covered: int = 0

    def add(self, gt: np.ndarray, det: np.ndarray | None, thin_width: float = THIN_WIDTH) -> None:
        """Count one ground truth ``bool [H, W]`` against its matched detection's mask
        ``bool [H, W]`` (``None``: unmatched, covers nothing)."""
        skeleton = skeletonize(gt)
        thin = skeleton & (local_width(gt) <= thin_width)
        self.instances += 1
        self.pixels += int(skeleton.sum())
        self.thin_pixels += int(thin.sum())
        if det is not None:
            self.matched += 1
            self.covered += int((skeleton & det).sum())
            self.thin_covered += int((thin & det).sum())

    def summary(self) -> dict:
        """``recall`` and ``thin_recall`` (covered / all skeleton pixels; ``None`` without
        any), plus the counts behind them."""
        return {
            "recall": self.covered / self.pixels if self.pixels else None,
            "thin_recall": self.thin_covered / self.thin_pixels if self.thin_pixels else None,
            "instances": self.instances,
            "matched": self.matched,
            "skeleton_pixels": self.pixels,
            "thin_pixels": self.thin_pixels,
        }
