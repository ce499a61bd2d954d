"""A grid of predictions drawn on source frames (masks tinted, boxes, class names)."""

from __future__ import annotations

import cv2
import numpy as np
import torch
from torch import nn

from slimseg.data.collate import make_collate, network_input
from slimseg.data.dataset import ZooDataset
from slimseg.data.sample import Sample
from slimseg.data.visualize import draw_class_map, draw_sample, tile
from slimseg.eval.validation import detect_batch, is_semantic
from slimseg.ops.nms import NMS_IOU, PREDICT_CONF
from slimseg.ops.semantic import logits_to_frame


def prediction_grid(
    model: nn.Module,
    dataset: ZooDataset,
    names: list[str],
    count: int = 8,
    columns: int = 4,
    conf: float = PREDICT_CONF,
) -> np.ndarray:
    """RGB grid of ``model``'s detections (score ≥ ``conf``) on the first ``count`` frames.

    ``dataset`` must be a validation ``ZooDataset`` (letterbox only): its letterbox meta maps
    detections back to each source frame, which is what the grid shows.
    """
    model.eval()
    count = min(count, len(dataset))
    batch = make_collate()([dataset[i] for i in range(count)])
    panels = []
    size = dataset.imgsz
    for _, source, panel in _panels(model, batch, dataset, names, conf):
        h, w = source.shape[:2]
        scale = size / max(h, w)
        if scale != 1:
            panel = cv2.resize(panel, (round(w * scale), round(h * scale)))
        canvas = np.full((size, size, 3), 255, np.uint8)
        canvas[: panel.shape[0], : panel.shape[1]] = panel
        panels.append(canvas)
    return tile(panels, columns)


def _panels(
    model: nn.Module, batch: dict, dataset: ZooDataset, names: list[str], conf: float
) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """``(index, source frame, drawn panel)``: class maps for semantic models, else masks
    and boxes."""
    out = []
    if is_semantic(model):
        with torch.no_grad():
            logits = model(network_input(batch["images"], next(model.parameters()).device)).cpu()
        for i, meta in enumerate(batch["meta"]):
            source = dataset.base[i].image
            class_map = logits_to_frame(logits[i], meta["letterbox"], source.shape[:2])
            out.append((i, source, draw_class_map(source, class_map.numpy(), names)))
        return out
    frames = detect_batch(model, batch, conf=conf, iou=NMS_IOU, max_det=100, mask_limit=None)
    for i, det in enumerate(frames):
        source = dataset.base[i].image
        h, w = source.shape[:2]
        masks = det.dense_masks().astype(np.uint8) if det.has_masks else None
        if masks is None:
            masks = np.zeros((len(det), h, w), np.uint8)
        shown = Sample(source, det.boxes, det.classes, masks)
        out.append((i, source, draw_sample(shown, names)))
    return out
