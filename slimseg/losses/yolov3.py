"""Darknet-style YOLOv3 loss (YOLO-SLAM, SEEDS §2) for anchor-based three-level heads.

Inputs are the raw training outputs of ``Darknet19YOLOv3``: one tensor per level
``[B, na, 5 + nc, h, w]`` with entries ``(tx, ty, tw, th, obj, cls_0, …)`` per anchor, decoded
as ``xy = (cell + σ(t_xy))·stride``, ``wh = exp(t_wh)·anchor``. Targets are the collate rows
``float32 [M, 6] = (batch_index, class, x1, y1, x2, y2)`` in input pixels.

Assignment (darknet ``yolo_layer.c``): every ground truth goes to the one anchor, among all
``L·na`` (9), whose box has the highest centred width/height IoU with it, at that anchor's
level, in the cell containing the box centre (cell indices clamped to the grid, so centres on
the right/bottom border land in the last cell). If several ground truths of one image land on
the same (level, anchor, cell) slot, the one appearing last in ``targets`` wins (darknet
overwrites the slot's deltas in truth order); the others get no positive.

Terms, each summed over predictions and divided by the batch size ``B`` (the loss is a mean
*per image*, so the learning rate does not depend on the batch size):

* ``box`` = λ_coord · Σ_pos (2 − w·h) · [KL(tx) + KL(ty) + ½(tw − tw*)² + ½(th − th*)²] with
  ``w``, ``h`` the ground truth size divided by the input width/height. ``tx* = cx/stride −
  col`` ∈ [0, 1] (likewise y), ``tw* = log(w_gt / w_anchor)``. ``KL(t) = BCE(σ(t), t*) −
  H(t*)`` is the binary cross entropy minus the target's entropy: same gradient as BCE, namely
  ``σ(t) − t*`` — exactly darknet's delta, which skips the logistic's derivative — but zero at a
  perfect prediction. The ½ on the squared size errors makes their gradient ``tw − tw*``, again
  darknet's delta. Sizes are regressed in log space on raw logits, so nothing is
  exponentiated on the gradient path.
* ``obj`` = Σ_pos BCE(obj, 1).
* ``noobj`` = λ_noobj · Σ_neg BCE(obj, 0) over every prediction that is neither assigned nor
  *ignored*: a prediction is ignored when its decoded box has IoU > ``ignore_iou`` with any
  ground truth of its image (darknet ``ignore_thresh``).
* ``cls`` = Σ_pos Σ_c BCE(cls_c, onehot_c). Kept for ``nc == 1`` (it is cheap); there it only
  pushes the single class logit towards 1 on positives.

All arithmetic runs in float32 (outputs are upcast), so the loss is safe under autocast.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from slimseg.ops.boxes import xywh_to_xyxy

# Decoded sizes are only needed (without gradient) for the ignore mask; cap exp() there.
_MAX_LOG_WH = 10.0


@dataclass(frozen=True)
class YOLOv3Assignment:
    """Positive slots, one per kept ground truth; every field is ``long [K]`` (``K ≤ M``).

    ``target`` indexes the rows of the ``targets`` tensor given to ``assign_targets``;
    ``level`` is the output level (0 = stride 8), ``anchor`` the anchor index within it,
    ``gj``/``gi`` the cell row/column and ``batch`` the image index.
    """

    target: torch.Tensor
    batch: torch.Tensor
    level: torch.Tensor
    anchor: torch.Tensor
    gj: torch.Tensor
    gi: torch.Tensor


def wh_iou(wh_a: torch.Tensor, wh_b: torch.Tensor) -> torch.Tensor:
    """IoU of centred boxes from sizes: ``wh_a [N, 2]``, ``wh_b [K, 2]`` → ``[N, K]``."""
    inter = torch.minimum(wh_a[:, None], wh_b[None]).prod(-1)
    area_a = wh_a.prod(-1)[:, None]
    area_b = wh_b.prod(-1)[None]
    return inter / (area_a + area_b - inter).clamp(min=1e-12)


def _valid_target_mask(targets: torch.Tensor) -> torch.Tensor:
    """``[M, 6]`` → ``bool [M]``: rows with positive width and height."""
    wh = targets[:, 4:6] - targets[:, 2:4]
    return (wh > 0).all(-1)


def assign_targets(
    targets: torch.Tensor,
    anchors: torch.Tensor,
    strides: Sequence[int],
    grid_hw: Sequence[tuple[int, int]],
) -> YOLOv3Assignment:
    """Darknet YOLOv3 matching of ground truths to (level, anchor, cell) slots.

    ``targets``: ``[M, 6]`` rows ``(batch_index, class, x1, y1, x2, y2)`` in input pixels;
    ``anchors``: ``[L, na, 2]`` (w, h) in pixels; ``strides``: ``L`` ints; ``grid_hw``: ``L``
    pairs ``(h, w)``, the output grid size of each level. Rows with non-positive width or height
    are dropped. Returns a ``YOLOv3Assignment`` with ``K`` entries (see the module docstring for
    the anchor rule, border clamping and duplicate-slot resolution). No loops over targets.
    """
    num_levels, na, _ = anchors.shape
    if len(strides) != num_levels or len(grid_hw) != num_levels:
        raise ValueError(
            f"{num_levels} anchor levels but {len(strides)} strides, {len(grid_hw)} grids"
        )
    device = targets.device
    keep = torch.nonzero(_valid_target_mask(targets)).squeeze(1)  # [K0]
    t = targets[keep].float()
    centre = (t[:, 2:4] + t[:, 4:6]) / 2  # [K0, 2] (cx, cy)
    wh = t[:, 4:6] - t[:, 2:4]  # [K0, 2]

    best = wh_iou(wh, anchors.reshape(-1, 2).to(device, torch.float32)).argmax(1)  # [K0]
    level = best // na
    anchor = best % na

    stride_t = torch.tensor(strides, device=device, dtype=torch.float32)[level]  # [K0]
    grid = torch.tensor(grid_hw, device=device, dtype=torch.long)[level]  # [K0, 2] (h, w)
    cell = torch.floor(centre / stride_t[:, None]).long()  # [K0, 2] (col, row)
    gi = torch.minimum(cell[:, 0].clamp(min=0), grid[:, 1] - 1)
    gj = torch.minimum(cell[:, 1].clamp(min=0), grid[:, 0] - 1)
    batch = t[:, 0].long()

    # One positive per slot: the last ground truth (in targets order) wins.
    if keep.numel():
        offsets = [0]
        for h, w in grid_hw:
            offsets.append(offsets[-1] + na * h * w)
        level_off = torch.tensor(offsets[:-1], device=device, dtype=torch.long)[level]
        per_image = offsets[-1]
        slot = batch * per_image + level_off + (anchor * grid[:, 0] + gj) * grid[:, 1] + gi
        order = torch.arange(keep.numel(), device=device)
        uniq, inverse = torch.unique(slot, return_inverse=True)
        winner = torch.full((uniq.numel(),), -1, device=device, dtype=torch.long)
        winner.scatter_reduce_(0, inverse, order, reduce="amax")
        sel = winner[inverse] == order
        keep, batch, level, anchor, gj, gi = (x[sel] for x in (keep, batch, level, anchor, gj, gi))
    return YOLOv3Assignment(keep, batch, level, anchor, gj, gi)


def _binary_kl_with_logits(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Elementwise ``BCE(σ(logits), target) − H(target)`` (≥ 0, zero when σ(logits) = target)."""
    entropy = -(torch.xlogy(target, target) + torch.xlogy(1 - target, 1 - target))
    return F.binary_cross_entropy_with_logits(logits, target, reduction="none") - entropy


def _pad_boxes_per_image(
    targets: torch.Tensor, batch_size: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """``[M, 6]`` → (xyxy ``[B, G, 4]``, valid ``bool [B, G]``), ``G`` = most boxes in an image."""
    b = targets[:, 0].long()
    counts = torch.bincount(b, minlength=batch_size)  # [B]
    g = int(counts.max()) if b.numel() else 0
    boxes = targets.new_zeros(batch_size, g, 4)
    valid = torch.zeros(batch_size, g, dtype=torch.bool, device=targets.device)
    if g:
        order = torch.argsort(b, stable=True)
        b_sorted = b[order]
        starts = torch.cumsum(counts, 0) - counts
        rank = torch.arange(b.numel(), device=b.device) - starts[b_sorted]
        boxes[b_sorted, rank] = targets[order, 2:6]
        valid[b_sorted, rank] = True
    return boxes, valid


def _max_iou(pred: torch.Tensor, gt: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Best IoU of each predicted box with the image's GTs.

    ``pred [B, N, 4]``, ``gt [B, G, 4]`` (xyxy), ``valid bool [B, G]`` → ``[B, N]``.
    """
    p = pred[:, :, None]  # [B, N, 1, 4]
    q = gt[:, None]  # [B, 1, G, 4]
    iw = (torch.minimum(p[..., 2], q[..., 2]) - torch.maximum(p[..., 0], q[..., 0])).clamp(min=0)
    ih = (torch.minimum(p[..., 3], q[..., 3]) - torch.maximum(p[..., 1], q[..., 1])).clamp(min=0)
    inter = iw * ih
    area_p = (p[..., 2] - p[..., 0]) * (p[..., 3] - p[..., 1])
    area_q = (q[..., 2] - q[..., 0]) * (q[..., 3] - q[..., 1])
    iou = inter / (area_p + area_q - inter).clamp(min=1e-9)
    return iou.masked_fill(~valid[:, None], 0.0).amax(-1)


class YOLOv3Loss:
    """Darknet-style YOLOv3 loss, per-image mean (see the module docstring for every term).

    Build from a model (``YOLOv3Loss(model)`` reads ``model.anchors``, ``model.strides`` and
    ``model.num_classes``) or from explicit ``anchors`` (``[L, na, 2]`` pixels, or nested
    ``((w, h), …)`` per level), ``strides`` and ``num_classes``. Anchors are moved to the
    outputs' device at each call, so the model may be moved after the loss is built.
    """

    def __init__(
        self,
        model: nn.Module | None = None,
        *,
        anchors: torch.Tensor | Sequence[Sequence[Sequence[float]]] | None = None,
        strides: Sequence[int] | None = None,
        num_classes: int | None = None,
        lambda_coord: float = 5.0,
        lambda_noobj: float = 0.5,
        ignore_iou: float = 0.7,
    ) -> None:
        if model is not None:
            anchors = model.anchors if anchors is None else anchors
            strides = model.strides if strides is None else strides
            num_classes = model.num_classes if num_classes is None else num_classes
        if anchors is None or strides is None or num_classes is None:
            raise ValueError("give a model or all of anchors, strides and num_classes")
        anchors_t = torch.as_tensor(anchors, dtype=torch.float32).detach().cpu()
        if anchors_t.ndim != 3 or anchors_t.shape[-1] != 2 or anchors_t.shape[0] != len(strides):
            raise ValueError(f"anchors must be [{len(strides)}, na, 2], got {anchors_t.shape}")
        self.anchors = anchors_t.clone()  # [L, na, 2]
        self.strides = tuple(int(s) for s in strides)
        self.num_classes = int(num_classes)
        self.lambda_coord = float(lambda_coord)
        self.lambda_noobj = float(lambda_noobj)
        self.ignore_iou = float(ignore_iou)

    def __call__(
        self,
        outputs: Sequence[torch.Tensor],
        targets: torch.Tensor,
        image_hw: int | tuple[int, int],
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Loss of raw outputs ``L × [B, na, 5+nc, h, w]`` against ``targets [M, 6]``.

        ``image_hw``: input size ``(H, W)`` (or one int for square inputs), used to normalise
        the box sizes in the ``2 − w·h`` weight. Returns the scalar total (mean per image,
        differentiable) and the detached terms ``{"box", "obj", "noobj", "cls"}``, each
        already weighted and per image, summing to the total.
        """
        num_levels, na, _ = self.anchors.shape
        if len(outputs) != num_levels:
            raise ValueError(f"expected {num_levels} output levels, got {len(outputs)}")
        preds = [p.float() for p in outputs]
        b, no = preds[0].shape[0], preds[0].shape[2]
        if no != 5 + self.num_classes or any(p.shape[1] != na for p in preds):
            raise ValueError(
                f"outputs must be [B, {na}, {5 + self.num_classes}, h, w], got "
                f"{[tuple(p.shape) for p in preds]}"
            )
        img_h, img_w = (image_hw, image_hw) if isinstance(image_hw, int) else image_hw
        device = preds[0].device
        anchors = self.anchors.to(device)
        targets = targets.to(device, torch.float32)
        targets = targets[_valid_target_mask(targets)]
        if targets.numel():
            bad_b = (targets[:, 0] < 0) | (targets[:, 0] >= b)
            bad_c = (targets[:, 1] < 0) | (targets[:, 1] >= self.num_classes)
            if bool((bad_b | bad_c).any()):
                raise ValueError(
                    f"targets hold batch indices outside [0, {b}) or classes "
                    f"outside [0, {self.num_classes})"
                )

        grid_hw = [(p.shape[3], p.shape[4]) for p in preds]
        asg = assign_targets(targets, anchors, self.strides, grid_hw)
        gt_boxes, gt_valid = _pad_boxes_per_image(targets, b)

        zero = preds[0].new_zeros(())
        box_sum, obj_sum, noobj_sum, cls_sum = zero, zero, zero, zero
        for lvl, (p, stride) in enumerate(zip(preds, self.strides, strict=True)):
            obj_logit = p[:, :, 4]  # [B, na, h, w]
            pos_mask = torch.zeros_like(obj_logit, dtype=torch.bool)

            on = asg.level == lvl
            bi, ai, gj, gi = asg.batch[on], asg.anchor[on], asg.gj[on], asg.gi[on]
            t = targets[asg.target[on]]  # [K, 6]
            if t.shape[0]:
                pos_mask[bi, ai, gj, gi] = True
                pp = p[bi, ai, :, gj, gi]  # [K, 5+nc]
                centre = (t[:, 2:4] + t[:, 4:6]) / 2
                wh = t[:, 4:6] - t[:, 2:4]
                cell = torch.stack((gi, gj), 1).float()
                txy = (centre / stride - cell).clamp(0.0, 1.0)
                twh = torch.log(wh / anchors[lvl, ai])
                scale = 2.0 - (wh[:, 0] / img_w) * (wh[:, 1] / img_h)  # [K]
                coord = _binary_kl_with_logits(pp[:, 0:2], txy).sum(1)
                coord = coord + 0.5 * (pp[:, 2:4] - twh).pow(2).sum(1)
                box_sum = box_sum + (scale * coord).sum()
                obj_sum = obj_sum + F.binary_cross_entropy_with_logits(
                    pp[:, 4], torch.ones_like(pp[:, 4]), reduction="sum"
                )
                onehot = F.one_hot(t[:, 1].long(), self.num_classes).float()
                cls_sum = cls_sum + F.binary_cross_entropy_with_logits(
                    pp[:, 5:], onehot, reduction="sum"
                )

            neg_mask = ~pos_mask
            if gt_valid.shape[1]:
                with torch.no_grad():
                    neg_mask &= ~self._ignored(p.detach(), lvl, anchors, gt_boxes, gt_valid)
            noobj = F.binary_cross_entropy_with_logits(
                obj_logit, torch.zeros_like(obj_logit), reduction="none"
            )
            noobj_sum = noobj_sum + (noobj * neg_mask).sum()

        terms = {
            "box": self.lambda_coord * box_sum / b,
            "obj": obj_sum / b,
            "noobj": self.lambda_noobj * noobj_sum / b,
            "cls": cls_sum / b,
        }
        total = terms["box"] + terms["obj"] + terms["noobj"] + terms["cls"]
        return total, {k: v.detach() for k, v in terms.items()}

    def _ignored(
        self,
        p: torch.Tensor,
        level: int,
        anchors: torch.Tensor,
        gt_boxes: torch.Tensor,
        gt_valid: torch.Tensor,
    ) -> torch.Tensor:
        """``bool [B, na, h, w]``: decoded box of ``p [B, na, 5+nc, h, w]`` has IoU >
        ``ignore_iou`` with a ground truth ``gt_boxes [B, G, 4]`` of its image."""
        b, na, _, h, w = p.shape
        stride = self.strides[level]
        ys = torch.arange(h, device=p.device, dtype=p.dtype)
        xs = torch.arange(w, device=p.device, dtype=p.dtype)
        gy, gx = torch.meshgrid(ys, xs, indexing="ij")
        grid = torch.stack((gx, gy), -1)  # [h, w, 2]
        xy = (p[:, :, 0:2].permute(0, 1, 3, 4, 2).sigmoid() + grid) * stride  # [B, na, h, w, 2]
        log_wh = p[:, :, 2:4].permute(0, 1, 3, 4, 2).clamp(max=_MAX_LOG_WH)
        wh = log_wh.exp() * anchors[level].view(1, na, 1, 1, 2)
        boxes = xywh_to_xyxy(torch.cat((xy, wh), -1)).reshape(b, na * h * w, 4)
        best = _max_iou(boxes, gt_boxes, gt_valid)  # [B, na·h·w]
        return (best > self.ignore_iou).view(b, na, h, w)
