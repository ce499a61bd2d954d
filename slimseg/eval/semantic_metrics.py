"""Semantic-segmentation metrics: mIoU and mean pixel accuracy (MPA) from a confusion matrix.

The confusion matrix ``M [K+1, K+1]`` (rows: ground truth, columns: prediction; index 0 =
background) is accumulated over every labelled pixel of the whole validation set (pixels
equal to ``IGNORE_INDEX`` are skipped). Per class ``k``::

    IoU_k = M[k, k] / (Σ_j M[k, j] + Σ_i M[i, k] − M[k, k])      (TP / (TP + FP + FN))
    PA_k  = M[k, k] / Σ_j M[k, j]                                 (TP / (TP + FN))

``miou`` and ``mpa`` average over classes *including background* (the VOC / VTD-SLAM
convention). A class absent from both the ground truth and the predictions has no IoU (0/0)
and is left out of the means; a class predicted but absent from the ground truth counts with
IoU 0 but has no PA (0/0) and is left out of the MPA. ``miou_fg`` is the mean IoU over the
foreground classes only; ``pixel_acc`` is the overall fraction of correct pixels.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from slimseg.ops.semantic import IGNORE_INDEX
from slimseg.utils.table import format_table


class ConfusionMatrix:
    """Accumulates ``[K+1, K+1]`` pixel counts; ``num_labels = K + 1`` (background included)."""

    def __init__(self, num_labels: int) -> None:
        self.num_labels = num_labels
        self.matrix = torch.zeros(num_labels, num_labels, dtype=torch.int64)

    def reset(self) -> None:
        self.matrix.zero_()

    def update(self, pred: torch.Tensor | np.ndarray, target: torch.Tensor | np.ndarray) -> None:
        """Add class maps ``pred`` and ``target`` (same shape, ints; target may hold
        ``IGNORE_INDEX``)."""
        pred = torch.as_tensor(pred).reshape(-1).long().cpu()
        target = torch.as_tensor(target).reshape(-1).long().cpu()
        if pred.shape != target.shape:
            raise ValueError(f"pred and target differ in size: {pred.numel()} vs {target.numel()}")
        keep = target != IGNORE_INDEX
        pred, target = pred[keep], target[keep]
        n = self.num_labels
        if len(target) and (int(target.max()) >= n or int(pred.max()) >= n):
            raise ValueError(f"class id out of range for {n} labels")
        self.matrix += torch.bincount(target * n + pred, minlength=n * n).reshape(n, n)

    def merge(self, other: ConfusionMatrix) -> None:
        self.matrix += other.matrix

    def compute(self, names: Sequence[str] | None = None) -> dict:
        """Metrics dict (see :func:`semantic_metrics`)."""
        return semantic_metrics(self.matrix.numpy(), names)


def _nanmean(values: list[float]) -> float:
    kept = [v for v in values if not math.isnan(v)]
    return float(np.mean(kept)) if kept else float("nan")


def semantic_metrics(matrix: np.ndarray, names: Sequence[str] | None = None) -> dict:
    """``matrix [K+1, K+1]`` (rows GT, columns prediction) → ``{"miou", "mpa", "miou_fg",
    "pixel_acc", "pixels", "per_class": [{"name", "iou", "pa", "gt_pixels",
    "pred_pixels"}, ...]}``; undefined per-class values are NaN (see the module doc)."""
    m = np.asarray(matrix, np.float64)
    tp = np.diag(m)
    gt = m.sum(axis=1)
    pred = m.sum(axis=0)
    union = gt + pred - tp
    with np.errstate(divide="ignore", invalid="ignore"):
        iou = np.where(union > 0, tp / union, np.nan)
        pa = np.where(gt > 0, tp / gt, np.nan)
    labels = ["background", *(names or [f"class{i}" for i in range(len(m) - 1)])]
    per_class = [
        {
            "name": labels[k],
            "iou": float(iou[k]),
            "pa": float(pa[k]),
            "gt_pixels": int(gt[k]),
            "pred_pixels": int(pred[k]),
        }
        for k in range(len(m))
    ]
    total = m.sum()
    return {
        "miou": _nanmean(list(iou)),
        "mpa": _nanmean(list(pa)),
        "miou_fg": _nanmean(list(iou[1:])),
        "pixel_acc": float(tp.sum() / total) if total else float("nan"),
        "pixels": int(total),
        "per_class": per_class,
    }


def format_semantic_table(result: dict) -> str:
    """Per-class IoU / PA table (percent) followed by the means."""

    def pct(v: float) -> object:
        return "-" if math.isnan(v) else round(100 * v, 2)

    rows = [
        [c["name"], pct(c["iou"]), pct(c["pa"]), c["gt_pixels"], c["pred_pixels"]]
        for c in result["per_class"]
    ]
    rows.append(["mean", pct(result["miou"]), pct(result["mpa"]), "", ""])
    table = format_table(["class", "IoU %", "PA %", "GT pixels", "predicted pixels"], rows)
    return (
        f"{table}\nmIoU {pct(result['miou'])} %, MPA {pct(result['mpa'])} % (background "
        f"included; foreground mIoU {pct(result['miou_fg'])} %), pixel accuracy "
        f"{pct(result['pixel_acc'])} %"
    )
