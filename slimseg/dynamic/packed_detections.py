"""One frame's detections kept small: each mask as its tight crop (a mask is zero outside its
box anyway), so a whole sequence of them fits in memory (the sweeps' detection cache, the
model results a real-time run received, replayed to score the other modes)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slimseg.detections import Prediction
from slimseg.dynamic.track_run import frame_dets


@dataclass(frozen=True)
class PackedDetections:
    """One frame's detections, frame pixels: ``boxes float32 [M, 4]`` xyxy, ``scores float32
    [M]``, ``classes int64 [M]``, each mask as ``(y0, x0, bool crop)`` (None: a
    detection-only model), frame size ``hw``."""

    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray
    crops: list[tuple[int, int, np.ndarray]] | None
    hw: tuple[int, int]

    @classmethod
    def pack(
        cls,
        boxes: np.ndarray,
        scores: np.ndarray,
        classes: np.ndarray,
        masks: np.ndarray | None,
        hw: tuple[int, int],
    ) -> PackedDetections:
        """From the full ``masks bool [M, H, W]`` (or None) of an ``hw`` frame."""
        crops = None if masks is None else [_crop(np.asarray(m, bool)) for m in masks]
        return cls(
            np.asarray(boxes, np.float32).reshape(-1, 4),
            np.asarray(scores, np.float32).reshape(-1),
            np.asarray(classes, np.int64).reshape(-1),
            crops,
            (int(hw[0]), int(hw[1])),
        )

    def select(self, conf: float, with_scores: bool = False) -> tuple:
        """The detections scoring above ``conf``: ``(boxes [m, 4], classes [m], masks bool
        [m, H, W] or None)``, in the cached (decreasing score) order; ``with_scores``: and
        ``scores [m]`` last."""
        keep = np.flatnonzero(self.scores > conf)
        masks = None
        if self.crops is not None:
            h, w = self.hw
            masks = np.zeros((len(keep), h, w), bool)
            for j, k in enumerate(keep):
                y0, x0, crop = self.crops[k]
                masks[j, y0 : y0 + crop.shape[0], x0 : x0 + crop.shape[1]] = crop
        if with_scores:
            return self.boxes[keep], self.classes[keep], masks, self.scores[keep]
        return self.boxes[keep], self.classes[keep], masks

    def prediction(self, conf: float) -> Prediction:
        """The detections scoring above ``conf`` as the model's result (names left empty)."""
        boxes, classes, masks, scores = self.select(conf, with_scores=True)
        return Prediction(boxes, scores, classes, [], [], masks, self.hw)

    @classmethod
    def of(cls, pred: Prediction, hw: tuple[int, int]) -> PackedDetections:
        """A model result (instances, or a semantic map's components scoring 1) packed."""
        d = frame_dets(pred, hw)
        return cls.pack(d.boxes, d.scores, d.classes, d.masks, d.hw)


def _crop(mask: np.ndarray) -> tuple[int, int, np.ndarray]:
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    if not len(rows):
        return 0, 0, np.zeros((0, 0), bool)
    y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    return int(y0), int(x0), mask[y0:y1, x0:x1].copy()
