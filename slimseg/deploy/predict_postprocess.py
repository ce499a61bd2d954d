"""Network outputs → :class:`~slimseg.detections.Prediction` per frame.

Instance models: :func:`~slimseg.ops.nms.non_max_suppression` (Darknet YOLOv3 rows first go
through :func:`~slimseg.models.registry.detection_rows`), then
:func:`~slimseg.eval.postprocess.to_frame_detections` (boxes and masks on the source frame).
Semantic models (``logits [B, K+1, H, W]``): cropped to the letterbox content, resized to the
frame and argmaxed into :attr:`Prediction.class_map`
(:func:`~slimseg.ops.semantic.logits_to_frame`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from slimseg.detections import Prediction
from slimseg.errors import SlimsegError
from slimseg.eval.postprocess import to_frame_detections
from slimseg.models.registry import detection_rows
from slimseg.ops.nms import non_max_suppression
from slimseg.ops.semantic import logits_to_frame


def instance_predictions(
    pred: torch.Tensor,
    proto: torch.Tensor | None,
    metas: Sequence[dict],
    names: list[str],
    mobility: list[float],
    family: str,
    conf: float,
    iou: float,
    max_det: int,
) -> list[Prediction]:
    """``pred [B, 4 + nc (+ nm), A]`` (``[B, 5 + nc, A]`` for YOLOv3) and ``proto
    [B, nm, H/s, W/s]`` → one :class:`Prediction` per frame of ``metas``."""
    nc = len(names)
    pred = detection_rows(family, pred)
    if pred.ndim != 3 or pred.shape[1] < 4 + nc:
        raise SlimsegError(
            f"model output {tuple(pred.shape)} does not match {nc} classes in its metadata"
        )
    dets = non_max_suppression(pred, nc, conf=conf, iou=iou, max_det=max_det)
    out = []
    for i, (d, meta) in enumerate(zip(dets, metas, strict=True)):
        frame = to_frame_detections(d, None if proto is None else proto[i], meta)
        classes = frame.classes
        out.append(
            Prediction(
                boxes=frame.boxes.astype(np.float32),
                scores=frame.scores.astype(np.float32),
                classes=classes,
                names=[names[c] for c in classes],
                mobility=[mobility[c] for c in classes],
                masks=frame.masks,
                image_hw=frame.image_hw,
            )
        )
    return out


def semantic_predictions(
    logits: torch.Tensor, metas: Sequence[dict], names: list[str]
) -> list[Prediction]:
    """``logits [B, K + 1, H, W]`` → one class-map :class:`Prediction` per frame."""
    nc = len(names)
    if logits.ndim != 4 or logits.shape[1] != nc + 1:
        raise SlimsegError(
            f"model output {tuple(logits.shape)} is not [B, {nc + 1}, H, W] "
            f"logits for the {nc} classes in its metadata"
        )
    dtype = np.uint8 if nc < 255 else np.int32
    out = []
    for i, meta in enumerate(metas):
        frame_hw = tuple(int(v) for v in meta["orig_shape"])
        class_map = logits_to_frame(logits[i], meta["letterbox"], frame_hw)
        out.append(
            Prediction(
                boxes=np.zeros((0, 4), np.float32),
                scores=np.zeros(0, np.float32),
                classes=np.zeros(0, np.int64),
                names=[],
                mobility=[],
                masks=None,
                image_hw=frame_hw,
                class_map=class_map.numpy().astype(dtype),
                class_names=list(names),
            )
        )
    return out
