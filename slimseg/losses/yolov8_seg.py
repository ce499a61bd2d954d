"""YOLOv8 detection / instance-segmentation loss.

Terms (each normalised as in the reference recipe, docs/architecture.md §6):
- ``box``: (1 − CIoU) between predicted and assigned boxes, weighted by the soft class target;
- ``dfl``: distribution focal loss on the 4 side distances (targets clamped to reg_max − 1.01);
- ``cls``: BCE of class logits against the task-aligned soft targets, / Σ targets;
- ``seg``: BCE of ``coeffs · protos`` against the GT instance mask at prototype resolution,
  cropped to the GT box and normalised by the box area, averaged over foreground anchors
  (:mod:`slimseg.losses.instance_mask`; its spec can move it to input resolution and add
  Dice and thin-part terms).
The total is ``(7.5·box + 1.5·dfl + 0.5·cls + 7.5·seg) × B`` (the reference scales by the
batch size so its SGD recipe carries over); the returned terms are before gains and ×B.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from slimseg.losses.instance_mask import InstanceMaskLoss
from slimseg.models.heads.decode import YOLO_STRIDES, anchor_points
from slimseg.models.specs import MaskLossSpec
from slimseg.models.yolo import RawOutputs
from slimseg.ops.assign import task_aligned_assign
from slimseg.ops.boxes import box_ciou_pairwise, box_to_distances, distances_to_box


@dataclass(frozen=True)
class LossGains:
    """Weights of the loss terms (YOLOv8 defaults)."""

    box: float = 7.5
    cls: float = 0.5
    dfl: float = 1.5
    seg: float = 7.5


def pad_targets(targets: torch.Tensor, batch_size: int) -> tuple[torch.Tensor, ...]:
    """``targets [M, 6]`` (b, cls, x1, y1, x2, y2) → per-image padded tensors.

    Returns ``labels [B, G]``, ``boxes [B, G, 4]``, ``valid [B, G]`` and ``rows [B, G]`` (the
    row of each slot in ``targets``, -1 for padding), ``G`` = most boxes in one image.
    """
    device = targets.device
    img = targets[:, 0].long()
    counts = torch.bincount(img, minlength=batch_size)
    g = int(counts.max()) if len(targets) else 0
    labels = torch.zeros(batch_size, g, dtype=torch.long, device=device)
    boxes = torch.zeros(batch_size, g, 4, device=device, dtype=targets.dtype)
    rows = torch.full((batch_size, g), -1, dtype=torch.long, device=device)
    if g:
        order = torch.argsort(img, stable=True)
        sorted_img = img[order]
        starts = torch.cumsum(counts, 0) - counts
        slot = torch.arange(len(order), device=device) - starts[sorted_img]
        labels[sorted_img, slot] = targets[order, 1].long()
        boxes[sorted_img, slot] = targets[order, 2:6]
        rows[sorted_img, slot] = order
    return labels, boxes, rows >= 0, rows


class YOLOv8Loss(nn.Module):
    """Loss for the ``yolov8*`` family (detect and segment, any head).

    ``forward(raw, targets, masks)``: ``raw`` from the training forward (``RawOutputs``),
    ``targets [M, 6]`` and ``masks [M, H/r, W/r]`` from ``slimseg.data.collate`` (``r`` =
    ``instance_mask.target_mask_ratio(spec)``). Returns ``(total, terms)`` with ``terms`` a
    dict of detached scalars.
    """

    def __init__(
        self,
        num_classes: int,
        strides: tuple[int, ...] = YOLO_STRIDES,
        reg_max: int = 16,
        gains: LossGains | None = None,
        topk: int = 10,
        alpha: float = 0.5,
        beta: float = 6.0,
        mask_loss: MaskLossSpec | None = None,
    ) -> None:
        super().__init__()
        self.nc, self.strides, self.reg_max = num_classes, strides, reg_max
        self.gains = gains or LossGains()
        self.topk, self.alpha, self.beta = topk, alpha, beta
        self.mask_loss = InstanceMaskLoss(mask_loss)
        self.register_buffer("bins", torch.arange(reg_max, dtype=torch.float32), persistent=False)

    def forward(
        self, raw: RawOutputs, targets: torch.Tensor, masks: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        feats = raw.feats
        b = feats[0].shape[0]
        sizes = [(f.shape[2], f.shape[3]) for f in feats]
        flat = torch.cat([f.reshape(b, f.shape[1], -1) for f in feats], 2).transpose(1, 2)
        flat = flat.float()
        distri, logits = flat.split((4 * self.reg_max, self.nc), dim=2)  # [B, A, ·]
        points, stride = anchor_points(sizes, self.strides, flat)  # grid units, [A, 1]
        probs = distri.reshape(b, -1, 4, self.reg_max).softmax(-1)
        pred_boxes = distances_to_box(points, probs @ self.bins)  # [B, A, 4] stride units

        targets = targets.to(flat.device, torch.float32)
        labels, gt_boxes, valid, rows = pad_targets(targets, b)
        assigned = task_aligned_assign(
            logits.detach().sigmoid(),
            pred_boxes.detach() * stride,
            points * stride,
            labels,
            gt_boxes,
            valid,
            self.topk,
            self.alpha,
            self.beta,
        )
        score_sum = assigned.scores.sum().clamp(min=1.0)
        cls = F.binary_cross_entropy_with_logits(logits, assigned.scores, reduction="none")
        cls = cls.sum() / score_sum

        box = dfl = seg = flat.sum() * 0.0
        fg = assigned.fg
        if fg.any():
            weight = assigned.scores.sum(-1)[fg]  # [n_fg]
            target = assigned.boxes / stride  # stride units
            ciou = box_ciou_pairwise(pred_boxes[fg], target[fg])
            box = ((1.0 - ciou) * weight).sum() / score_sum
            tdist = box_to_distances(points.expand(b, -1, -1)[fg], target[fg], self.reg_max - 1.01)
            dfl = (self._dfl(distri[fg].reshape(-1, self.reg_max), tdist) * weight).sum()
            dfl = dfl / score_sum

        total = self.gains.box * box + self.gains.cls * cls + self.gains.dfl * dfl
        terms = {"box": box, "cls": cls, "dfl": dfl}
        if raw.proto is not None:
            # the zero terms keep every mask parameter in the graph when nothing is assigned
            seg = seg + raw.proto.sum() * 0.0 + raw.mask_coeffs.sum() * 0.0
            if fg.any():
                input_hw = (sizes[0][0] * self.strides[0], sizes[0][1] * self.strides[0])
                seg = seg + self.mask_loss(
                    raw.proto, raw.mask_coeffs, assigned, rows, masks, input_hw
                )
            total = total + self.gains.seg * seg
            terms["seg"] = seg
        return total * b, {k: v.detach() for k, v in terms.items()}

    @staticmethod
    def _dfl(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """``logits [n·4, reg_max]``, ``target [n, 4]`` (bin units) → per-box loss ``[n]``."""
        t = target.reshape(-1)
        left = t.floor().long()
        w_right = t - left
        ce_left = F.cross_entropy(logits, left, reduction="none")
        ce_right = F.cross_entropy(logits, left + 1, reduction="none")
        return (ce_left * (1 - w_right) + ce_right * w_right).view(-1, 4).mean(-1)
