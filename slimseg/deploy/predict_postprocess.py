"""Network outputs → :class:`~slimseg.detections.Prediction` per frame, in numpy (no torch).

What every predictor runs, whichever backend produced the outputs, so the core install (no
torch) and the full one give the same detections. Instance models:
:func:`~slimseg.ops.nms_numpy.nms_rows` (Darknet YOLOv3 rows first go through
:func:`~slimseg.ops.nms_numpy.detection_rows`), boxes back to the frame
(:func:`~slimseg.ops.letterbox.boxes_to_frame`) and masks on the frame
(:func:`~slimseg.ops.masks_numpy.frame_masks`): the rule of the torch path that validation
runs (``slimseg.ops.nms``, ``slimseg.eval.postprocess``), step for step. Semantic models
(``logits [B, K+1, H, W]``): cropped to the letterbox content, resized bilinearly to the frame
and argmaxed into :attr:`Prediction.class_map` (:func:`semantic_class_map`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from slimseg.detections import Prediction
from slimseg.errors import SlimsegError
from slimseg.ops.letterbox import LetterboxParams, boxes_to_frame
from slimseg.ops.masks_numpy import bilinear_taps, frame_masks, resample
from slimseg.ops.nms_numpy import detection_rows, nms_rows


def instance_predictions(
    pred: np.ndarray,
    proto: np.ndarray | None,
    metas: Sequence[dict],
    names: list[str],
    mobility: list[float],
    family: str,
    conf: float,
    iou: float,
    max_det: int,
) -> list[Prediction]:
    """``pred float32 [B, 4 + nc (+ nm), A]`` (``[B, 5 + nc, A]`` for YOLOv3) and ``proto
    float32 [B, nm, H/s, W/s]`` → one :class:`Prediction` per frame of ``metas``."""
    nc = len(names)
    pred = detection_rows(family, np.asarray(pred, np.float32))
    if pred.ndim != 3 or pred.shape[1] < 4 + nc:
        raise SlimsegError(
            f"model output {tuple(pred.shape)} does not match {nc} classes in its metadata"
        )
    out = []
    for i, meta in enumerate(metas):
        p: LetterboxParams = meta["letterbox"]
        h, w = (int(v) for v in meta["orig_shape"])
        boxes, scores, classes, coeffs = nms_rows(pred[i], nc, conf=conf, iou=iou, max_det=max_det)
        masks = None
        if proto is not None:
            if coeffs.shape[1] != proto.shape[1]:
                raise SlimsegError(
                    f"model output: proto has {proto.shape[1]} channels but the detections "
                    f"carry {coeffs.shape[1]} mask coefficients"
                )
            masks = frame_masks(coeffs, np.asarray(proto[i], np.float32), boxes, p, (h, w))
        out.append(frame_prediction(boxes, scores, classes, masks, names, mobility, p, (h, w)))
    return out


def frame_prediction(
    boxes: np.ndarray,
    scores: np.ndarray,
    classes: np.ndarray,
    masks: np.ndarray | None,
    names: list[str],
    mobility: list[float],
    p: LetterboxParams,
    frame_hw: tuple[int, int],
) -> Prediction:
    """One frame's :class:`Prediction`: ``boxes [N, 4]`` xyxy in network-input pixels mapped
    back to the ``frame_hw`` frame through ``p``; ``scores [N]``, ``classes int [N]`` with their
    ``names`` and ``mobility`` looked up; ``masks bool [N, H, W]`` (frame pixels) or None."""
    h, w = frame_hw
    return Prediction(
        boxes=boxes_to_frame(np.asarray(boxes).reshape(-1, 4), p, h, w),
        scores=scores,
        classes=classes,
        names=[names[c] for c in classes],
        mobility=[mobility[c] for c in classes],
        masks=masks,
        image_hw=(h, w),
    )


def semantic_class_map(
    logits: np.ndarray, p: LetterboxParams, frame_hw: tuple[int, int]
) -> np.ndarray:
    """One image's logits ``[K+1, H, W]`` at the network input → ``int64 [h, w]`` class map on
    the source frame: the letterbox content, resized bilinearly (half-pixel centres, the rule
    of :mod:`slimseg.ops.masks_numpy`) to ``h × w``, argmax over classes (first of equals)."""
    crop = np.asarray(logits[:, p.top : p.top + p.new_h, p.left : p.left + p.new_w], np.float32)
    h, w = frame_hw
    if crop.shape[1:] != (h, w):
        ys = bilinear_taps(0, h, h, p.new_h)
        xs = bilinear_taps(0, w, w, p.new_w)
        crop = np.stack([resample(c, ys, xs) for c in crop])
    return crop.argmax(axis=0)


def semantic_predictions(
    logits: np.ndarray, metas: Sequence[dict], names: list[str]
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
        class_map = semantic_class_map(logits[i], meta["letterbox"], frame_hw)
        out.append(
            Prediction(
                boxes=np.zeros((0, 4), np.float32),
                scores=np.zeros(0, np.float32),
                classes=np.zeros(0, np.int64),
                names=[],
                mobility=[],
                masks=None,
                image_hw=frame_hw,
                class_map=class_map.astype(dtype),
                class_names=list(names),
            )
        )
    return out
