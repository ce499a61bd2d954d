"""Task-aligned assignment (TOOD / YOLOv8): which anchors learn which ground-truth box.

Pure tensor function: no model, no loss. Shapes use ``B`` images, ``G`` padded ground-truth
slots per image, ``A`` anchors and ``C`` classes.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from slimseg.ops.boxes import box_ciou_pairwise


class Assignment(NamedTuple):
    """``fg [B, A]`` bool; ``gt_index [B, A]`` slot of the assigned GT (0 where not fg);
    ``boxes [B, A, 4]`` xyxy of the assigned GT; ``scores [B, A, C]`` soft class targets."""

    fg: torch.Tensor
    gt_index: torch.Tensor
    boxes: torch.Tensor
    scores: torch.Tensor


@torch.no_grad()
def task_aligned_assign(
    pred_scores: torch.Tensor,
    pred_boxes: torch.Tensor,
    points: torch.Tensor,
    gt_labels: torch.Tensor,
    gt_boxes: torch.Tensor,
    gt_valid: torch.Tensor,
    topk: int = 10,
    alpha: float = 0.5,
    beta: float = 6.0,
    eps: float = 1e-9,
) -> Assignment:
    """Assign anchors to ground truth by ``align = score^α · CIoU^β``.

    ``pred_scores [B, A, C]`` (sigmoid), ``pred_boxes [B, A, 4]`` xyxy px, ``points [A, 2]``
    anchor centres px, ``gt_labels [B, G]`` int64, ``gt_boxes [B, G, 4]`` xyxy px,
    ``gt_valid [B, G]`` bool. Candidates are anchors whose centre lies strictly inside a GT
    box; each GT keeps its ``topk`` best-aligned candidates; an anchor claimed by several GTs
    keeps the one it overlaps most. Class targets are one-hot scaled by
    ``align / max_align(GT) · max_IoU(GT)``.
    """
    b, a, c = pred_scores.shape
    g = gt_boxes.shape[1]
    device = pred_scores.device
    if g == 0:
        return Assignment(
            torch.zeros(b, a, dtype=torch.bool, device=device),
            torch.zeros(b, a, dtype=torch.long, device=device),
            torch.zeros(b, a, 4, device=device),
            torch.zeros(b, a, c, device=device),
        )
    # candidates: anchor centre strictly inside the GT box  [B, G, A]
    lt = points.view(1, 1, a, 2) - gt_boxes[:, :, None, :2]
    rb = gt_boxes[:, :, None, 2:] - points.view(1, 1, a, 2)
    inside = torch.cat((lt, rb), -1).amin(-1) > eps
    candidate = inside & gt_valid[:, :, None]

    iou = box_ciou_pairwise(gt_boxes[:, :, None, :], pred_boxes[:, None, :, :]).clamp_(min=0)
    iou = iou * candidate
    labels = gt_labels.clamp(min=0).long()
    cls_score = pred_scores.gather(2, labels[:, None, :].expand(b, a, g)).transpose(1, 2)
    align = cls_score.pow(alpha) * iou.pow(beta) * candidate  # [B, G, A]

    k = min(topk, a)
    top_idx = align.topk(k, dim=-1).indices  # [B, G, k]
    top = torch.zeros_like(align, dtype=torch.bool).scatter_(-1, top_idx, True)
    pos = top & candidate  # [B, G, A]

    # anchors claimed by several GTs keep the GT with the highest IoU
    claims = pos.sum(1)  # [B, A]
    if (claims > 1).any():
        best = iou.argmax(1)  # [B, A]
        best_onehot = torch.zeros_like(pos).scatter_(1, best[:, None, :], True)
        pos = torch.where((claims > 1)[:, None, :], best_onehot & candidate, pos)
    fg = pos.any(1)  # [B, A]
    gt_index = pos.float().argmax(1)  # [B, A]

    boxes = gt_boxes.gather(1, gt_index[..., None].expand(b, a, 4))
    assigned_labels = labels.gather(1, gt_index)
    align = align * pos
    best_iou = (iou * pos).amax(-1, keepdim=True)
    norm = (align * best_iou / (align.amax(-1, keepdim=True) + eps)).amax(1)
    scores = torch.zeros(b, a, c, device=device, dtype=pred_scores.dtype)
    scores.scatter_(2, assigned_labels[..., None], 1.0)
    scores = scores * (norm * fg)[..., None]
    return Assignment(fg, gt_index, boxes, scores)
