"""A grid of predictions drawn on source frames (masks tinted, boxes, class names)."""

from __future__ import annotations

import cv2
import numpy as np
from torch import nn

from slimseg.data.collate import make_collate
from slimseg.data.dataset import YoloDataset
from slimseg.data.sample import Sample
from slimseg.data.visualize import draw_sample, tile
from slimseg.engine.evaluate import detect_batch


def prediction_grid(
    model: nn.Module,
    dataset: YoloDataset,
    names: list[str],
    count: int = 8,
    columns: int = 4,
    conf: float = 0.25,
) -> np.ndarray:
    """RGB grid of ``model``'s detections (score ≥ ``conf``) on the first ``count`` frames.

    ``dataset`` must be a validation ``YoloDataset`` (letterbox only): its letterbox meta maps
    detections back to each source frame, which is what the grid shows.
    """
    model.eval()
    count = min(count, len(dataset))
    batch = make_collate()([dataset[i] for i in range(count)])
    frames = detect_batch(model, batch, conf=conf, iou=0.7, max_det=100)
    panels = []
    size = dataset.imgsz
    for i, det in enumerate(frames):
        source = dataset.base[i].image
        h, w = source.shape[:2]
        masks = det.dense_masks().astype(np.uint8) if det.has_masks else None
        if masks is None:
            masks = np.zeros((len(det), h, w), np.uint8)
        shown = Sample(source, det.boxes, det.classes, masks)
        panel = draw_sample(shown, names)
        scale = size / max(h, w)
        if scale != 1:
            panel = cv2.resize(panel, (round(w * scale), round(h * scale)))
        canvas = np.full((size, size, 3), 255, np.uint8)
        canvas[: panel.shape[0], : panel.shape[1]] = panel
        panels.append(canvas)
    return tile(panels, columns)
