"""Pure box functions: format conversion, IoU/CIoU, side distances (torch); the box-to-pixel
rule is :func:`~slimseg.ops.box_pixels.box_pixel_bounds` (no torch), re-exported here."""

from __future__ import annotations

import math

import torch

from slimseg.ops.box_pixels import box_pixel_bounds

__all__ = [
    "box_ciou_pairwise",
    "box_iou_pairwise",
    "box_pixel_bounds",
    "box_to_distances",
    "distances_to_box",
    "xywh_to_xyxy",
    "xyxy_to_xywh",
]


def xywh_to_xyxy(boxes: torch.Tensor) -> torch.Tensor:
    """``[..., 4]`` centre-size boxes → corner boxes ``[..., 4]``."""
    c, wh = boxes[..., :2], boxes[..., 2:4]
    return torch.cat((c - wh / 2, c + wh / 2), dim=-1)


def xyxy_to_xywh(boxes: torch.Tensor) -> torch.Tensor:
    """``[..., 4]`` corner boxes → centre-size boxes ``[..., 4]``."""
    p1, p2 = boxes[..., :2], boxes[..., 2:4]
    return torch.cat(((p1 + p2) / 2, p2 - p1), dim=-1)


def box_iou_pairwise(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-7) -> torch.Tensor:
    """IoU of aligned pairs of xyxy boxes: ``a [..., 4]``, ``b [..., 4]`` → ``[...]``."""
    lt = torch.maximum(a[..., :2], b[..., :2])
    rb = torch.minimum(a[..., 2:], b[..., 2:])
    inter = (rb - lt).clamp(min=0).prod(-1)
    area_a = (a[..., 2:] - a[..., :2]).clamp(min=0).prod(-1)
    area_b = (b[..., 2:] - b[..., :2]).clamp(min=0).prod(-1)
    return inter / (area_a + area_b - inter + eps)


def box_ciou_pairwise(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-7) -> torch.Tensor:
    """Complete IoU of aligned pairs of xyxy boxes ``[..., 4]`` → ``[...]`` (in [-1.5, 1]).

    ``CIoU = IoU − ρ²/c² − α·v`` with ρ the centre distance, c the diagonal of the enclosing
    box, ``v = 4/π² (atan(w_b/h_b) − atan(w_a/h_a))²`` and ``α = v / (1 − IoU + v)``.
    """
    iou = box_iou_pairwise(a, b, eps)
    wa, ha = a[..., 2] - a[..., 0], a[..., 3] - a[..., 1] + eps
    wb, hb = b[..., 2] - b[..., 0], b[..., 3] - b[..., 1] + eps
    enclose = torch.maximum(a[..., 2:], b[..., 2:]) - torch.minimum(a[..., :2], b[..., :2])
    c2 = enclose.pow(2).sum(-1) + eps
    rho2 = ((a[..., :2] + a[..., 2:]) - (b[..., :2] + b[..., 2:])).pow(2).sum(-1) / 4
    v = (4 / math.pi**2) * (torch.atan(wb / hb) - torch.atan(wa / ha)).pow(2)
    with torch.no_grad():
        alpha = v / (v - iou + (1 + eps))
    return iou - (rho2 / c2 + v * alpha)


def box_to_distances(points: torch.Tensor, boxes: torch.Tensor, limit: float) -> torch.Tensor:
    """Distances (left, top, right, bottom) from ``points [..., 2]`` to the sides of xyxy
    ``boxes [..., 4]``, clamped to ``[0, limit]`` → ``[..., 4]`` (DFL regression targets)."""
    lt = points - boxes[..., :2]
    rb = boxes[..., 2:] - points
    return torch.cat((lt, rb), dim=-1).clamp(0, limit)


def distances_to_box(points: torch.Tensor, dist: torch.Tensor) -> torch.Tensor:
    """Inverse of ``box_to_distances``: ``points [..., 2]``, ``dist [..., 4]`` → xyxy boxes."""
    return torch.cat((points - dist[..., :2], points + dist[..., 2:]), dim=-1)
