"""Non-maximum suppression in numpy: the runtime's decoding of a network's rows (no torch).

The same rule as :mod:`slimseg.ops.nms` (its module docstring), with the same float32
arithmetic as torchvision's CPU kernel, so both keep the same detections in the same order:

- candidates: best class per anchor (the first of equal scores), ``score > conf``, the
  ``max_candidates`` best if more remain; boxes ``xywh → xyxy`` in float32;
- class-aware NMS as ``torchvision.ops.batched_nms`` does it on a CPU: up to 1000
  candidates, one NMS over boxes shifted by ``class · (max coordinate + 1)`` (the shift
  changes the boxes' float rounding, so it is reproduced); above 1000, one NMS per class and
  the survivors sorted by decreasing score;
- greedy NMS: candidates by decreasing score (stable: equal scores keep anchor order), a box
  suppresses every later one whose IoU ``inter / (area_i + area_j − inter)``, float32, is
  above ``iou`` (compared in float64; ``score > conf`` in float32, as torch compares).

Also the one home of the detection-style thresholds (``docs/conventions.md`` §6).
"""

from __future__ import annotations

import numpy as np

# Detection-style thresholds, one home (``docs/conventions.md`` §6). SLAM-facing thresholds
# for dynamic masking are a separate family (``slimseg.dynamic``).
EVAL_CONF = 0.001  # mAP evaluation: keep nearly everything, COCOeval ranks it
PREDICT_CONF = 0.25  # predictions shown or saved
NMS_IOU = 0.7  # suppress overlaps strictly above this IoU
MAX_DET = 300  # detections kept per image

#: above this many candidates torchvision's CPU ``batched_nms`` runs one NMS per class
PER_CLASS_ABOVE = 1000


def yolov3_rows(pred: np.ndarray) -> np.ndarray:
    """Darknet YOLOv3 eval output ``[B, 5 + nc, A]`` (``cx, cy, w, h``, objectness, class
    probabilities) → ``[B, 4 + nc, A]`` rows, class score = objectness · class probability."""
    if pred.ndim != 3 or pred.shape[1] < 6:
        raise ValueError(f"expected a [B, 5+nc, A] YOLOv3 output, got {tuple(pred.shape)}")
    return np.concatenate((pred[:, :4], pred[:, 4:5] * pred[:, 5:]), axis=1)


def detection_rows(family: str, pred: np.ndarray) -> np.ndarray:
    """The eval output of a model of ``family`` (an export's metadata) → rows ``[B, 4 + nc +
    nm, A]`` (what :func:`slimseg.models.registry.detection_rows` does to torch tensors)."""
    return yolov3_rows(pred) if family == "darknet-yolov3" else pred


def greedy_nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> np.ndarray:
    """Indices ``int64 [K]`` of the xyxy ``boxes float32 [N, 4]`` kept by greedy NMS, in
    decreasing score order (``scores float32 [N]``, stable sort); see the module docstring."""
    order = np.argsort(-scores, kind="stable")
    if len(order) == 0:
        return order.astype(np.int64)
    b = boxes[order]
    x1, y1, x2, y2 = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    areas = (x2 - x1) * (y2 - y1)
    zero, limit = np.float32(0), np.float64(iou)  # torchvision compares in double
    suppressed = np.zeros(len(order), bool)
    keep = []
    with np.errstate(divide="ignore", invalid="ignore"):  # 0 / 0 (empty boxes): no overlap
        for i in range(len(order)):
            if suppressed[i]:
                continue
            keep.append(i)
            w = np.maximum(zero, np.minimum(x2[i], x2[i + 1 :]) - np.maximum(x1[i], x1[i + 1 :]))
            h = np.maximum(zero, np.minimum(y2[i], y2[i + 1 :]) - np.maximum(y1[i], y1[i + 1 :]))
            inter = w * h
            overlap = inter / (areas[i] + areas[i + 1 :] - inter)
            suppressed[i + 1 :] |= overlap > limit
    return order[np.asarray(keep, np.int64)]


def batched_nms(
    boxes: np.ndarray, scores: np.ndarray, groups: np.ndarray, iou: float
) -> np.ndarray:
    """Greedy NMS within each group (class) of ``groups int [N]``: kept indices ``int64
    [K]`` by decreasing score, as torchvision's CPU ``batched_nms`` (module docstring)."""
    if len(boxes) == 0:
        return np.zeros(0, np.int64)
    if len(boxes) <= PER_CLASS_ABOVE:
        offsets = groups.astype(np.float32) * (boxes.max() + np.float32(1))
        return greedy_nms(boxes + offsets[:, None], scores, iou)
    kept = np.zeros(len(boxes), bool)
    for g in np.unique(groups):
        members = np.flatnonzero(groups == g)
        kept[members[greedy_nms(boxes[members], scores[members], iou)]] = True
    idx = np.flatnonzero(kept)
    return idx[np.argsort(-scores[idx], kind="stable")]


def nms_rows(
    rows: np.ndarray,
    nc: int,
    conf: float = EVAL_CONF,
    iou: float = NMS_IOU,
    max_det: int = MAX_DET,
    agnostic: bool = False,
    max_candidates: int = 30000,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One image's rows ``[4 + nc + nm, A]`` (float32) → ``(boxes float32 [N, 4] xyxy input
    pixels, scores float32 [N], classes int64 [N], coeffs float32 [N, nm])``, by decreasing
    score. Arguments as :func:`slimseg.ops.nms.non_max_suppression`."""
    if rows.ndim != 2 or nc < 1 or rows.shape[0] < 4 + nc:
        raise ValueError(f"expected rows [4+nc+nm, A] with nc={nc}, got {tuple(rows.shape)}")
    cls_scores = rows[4 : 4 + nc]
    classes = cls_scores.argmax(axis=0)
    scores = np.take_along_axis(cls_scores, classes[None], axis=0)[0]
    keep = np.flatnonzero(scores > conf)
    if len(keep) > max_candidates:
        keep = keep[np.argsort(-scores[keep], kind="stable")[:max_candidates]]
    x = rows[:, keep].T.astype(np.float32, copy=False)  # [K, 4 + nc + nm]
    scores, classes = scores[keep].astype(np.float32, copy=False), classes[keep]
    half = x[:, 2:4] / np.float32(2)
    boxes = np.concatenate((x[:, :2] - half, x[:, :2] + half), axis=1)
    groups = np.zeros_like(classes) if agnostic else classes
    idx = batched_nms(boxes, scores, groups, iou)[:max_det]
    return boxes[idx], scores[idx], classes[idx].astype(np.int64), x[idx, 4 + nc :]
