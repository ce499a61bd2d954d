"""Non-maximum suppression over the raw eval output of every detector in the project.

One layout serves all models: ``pred [B, 4 + nc + nm, A]`` with rows ``cx, cy, w, h`` (input
pixels), ``nc`` class scores in ``[0, 1]`` and ``nm`` mask coefficients (``nm = 0`` for
detection heads). Darknet YOLOv3 output is first converted with :func:`yolov3_to_rows`.

Rule (what a C++ runtime should do to reproduce it), per image:

1. each anchor keeps its best class only (``score, cls = max over the nc rows``): single
   label per anchor, as YOLOv8 validation does by default (no multi-label expansion);
2. drop anchors with ``score <= conf``;
3. if more than ``max_candidates`` remain, keep the ``max_candidates`` highest scores;
4. boxes ``xywh → xyxy``; greedy NMS at IoU ``> iou`` within each class (all classes
   together with ``agnostic=True``), via :func:`torchvision.ops.batched_nms`;
5. keep the ``max_det`` highest-scoring survivors, sorted by decreasing score.

:mod:`slimseg.ops.nms_numpy` is the same rule in numpy (what the runtime runs, no torch).
"""

from __future__ import annotations

import torch
from torchvision.ops import batched_nms

from slimseg.detections import Detections
from slimseg.ops.boxes import xywh_to_xyxy

# the detection-style thresholds' home is the torch-free twin (docs/conventions.md §6)
from slimseg.ops.nms_numpy import EVAL_CONF, MAX_DET, NMS_IOU, PREDICT_CONF

__all__ = [
    "EVAL_CONF",
    "MAX_DET",
    "NMS_IOU",
    "PREDICT_CONF",
    "non_max_suppression",
    "yolov3_to_rows",
]


def yolov3_to_rows(pred: torch.Tensor) -> torch.Tensor:
    """Darknet YOLOv3 eval output ``[B, 5 + nc, A]`` (``cx, cy, w, h``, objectness, class
    probabilities, all after sigmoid) → ``[B, 4 + nc, A]`` with class score = obj · cls."""
    if pred.ndim != 3 or pred.shape[1] < 6:
        raise ValueError(f"expected a [B, 5+nc, A] YOLOv3 output, got {tuple(pred.shape)}")
    return torch.cat((pred[:, :4], pred[:, 4:5] * pred[:, 5:]), dim=1)


def non_max_suppression(
    pred: torch.Tensor,
    nc: int,
    conf: float = EVAL_CONF,
    iou: float = NMS_IOU,
    max_det: int = MAX_DET,
    agnostic: bool = False,
    max_candidates: int = 30000,
) -> list[Detections]:
    """Per-image NMS of ``pred [B, 4 + nc + nm, A]`` → ``B`` :class:`Detections`.

    ``conf``: keep scores strictly above it; ``iou``: suppress overlaps strictly above it;
    ``max_det``: detections kept per image; ``agnostic``: suppress across classes;
    ``max_candidates``: cap on the boxes entering NMS (highest scores kept). See the module
    docstring for the exact rule. Outputs stay on ``pred``'s device and dtype.
    """
    if pred.ndim != 3 or nc < 1 or pred.shape[1] < 4 + nc:
        raise ValueError(f"expected pred [B, 4+nc+nm, A] with nc={nc}, got {tuple(pred.shape)}")
    nm = pred.shape[1] - 4 - nc
    out: list[Detections] = []
    for x in pred.detach().transpose(1, 2):  # [A, 4 + nc + nm] per image
        scores, classes = x[:, 4 : 4 + nc].max(dim=1)
        keep = (scores > conf).nonzero().squeeze(1)
        if keep.numel() > max_candidates:
            keep = keep[scores[keep].topk(max_candidates).indices]
        x, scores, classes = x[keep], scores[keep], classes[keep]
        boxes = xywh_to_xyxy(x[:, :4])
        groups = torch.zeros_like(classes) if agnostic else classes
        idx = batched_nms(boxes.float(), scores.float(), groups, iou)[:max_det]
        out.append(
            Detections(
                boxes=boxes[idx],
                scores=scores[idx],
                classes=classes[idx].long(),
                coeffs=x[idx, 4 + nc :] if nm else x.new_zeros((idx.numel(), 0)),
            )
        )
    return out
