"""The YOLOv8-seg instance-mask term, at prototype or at input resolution.

Per foreground anchor ``a`` assigned to ground-truth instance ``g`` with box ``b``:
``logits = coeffs_a · protos`` and, over the target pixels whose centres lie in ``b``
(``ops.boxes.box_pixel_bounds``),

    seg_a = Σ w · BCE(logits, gt_g) / area(b)  +  dice · (1 − (2 Σ σ·gt + 1) / (Σ σ + Σ gt + 1))

with ``w = 1 + thin`` on thin ground-truth pixels (removed by a 5 × 5 opening) and 1
elsewhere; the term is the mean of ``seg_a`` over all foreground anchors of the batch. With
``dice = thin = 0`` and ``resolution: proto`` this is the reference loss exactly.

Resolutions (``MaskLossSpec.resolution``):
- ``proto``: the ground truth is brought to the prototype grid (nearest, if the batch does
  not already hold it there: the collate's block rule does that) and the logits stay there;
- ``input``: the prototypes of each image are upsampled bilinearly (half-pixel centres) to
  the ground truth's resolution, the input resolution when the collate keeps full masks
  (``target_mask_ratio``). Upsampling is linear, so this equals upsampling every anchor's
  logits, at a fraction of the memory; only each instance's box window is ever used.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from slimseg.models.specs import MaskLossSpec, ModelSpec
from slimseg.ops.assign import Assignment
from slimseg.ops.boxes import box_pixel_bounds

THIN_OPENING = 5  # px at the target resolution: parts narrower than this count as thin


def target_mask_ratio(spec: ModelSpec) -> int:
    """Input size / size of the ground-truth masks the collate must deliver for ``spec``."""
    head = spec.head
    return 1 if head.mask_loss.resolution == "input" else head.proto_stride


def thin_parts(masks: torch.Tensor, size: int = THIN_OPENING) -> torch.Tensor:
    """``float [M, H, W]`` 0/1 masks → 0/1 map of the pixels a ``size × size`` opening removes."""
    x = masks[:, None]
    pad = size // 2
    eroded = -F.max_pool2d(-x, size, 1, pad)
    opened = F.max_pool2d(eroded, size, 1, pad)
    return (x - opened).clamp(min=0.0)[:, 0]


class InstanceMaskLoss:
    """``__call__(proto, coeffs, assigned, rows, masks, input_hw) → scalar`` (see module doc).

    ``proto [B, nm, Hp, Wp]``, ``coeffs [B, nm, A]``, ``assigned`` the task-aligned
    assignment (boxes in input pixels), ``rows [B, G]`` the row of every padded target slot
    in ``masks [M, Hm, Wm]`` (0/1), ``input_hw`` the network input size.
    """

    def __init__(self, spec: MaskLossSpec | None = None) -> None:
        self.spec = spec or MaskLossSpec()

    def __call__(
        self,
        proto: torch.Tensor,
        coeffs: torch.Tensor,
        assigned: Assignment,
        rows: torch.Tensor,
        masks: torch.Tensor | None,
        input_hw: tuple[int, int],
    ) -> torch.Tensor:
        if masks is None:
            raise ValueError("the segmentation loss needs the batch's instance masks")
        proto = proto.float()
        gt_all = masks.to(proto.device).float()
        if self.spec.resolution == "proto" and gt_all.shape[1:] != proto.shape[2:]:
            gt_all = F.interpolate(gt_all[None], proto.shape[2:], mode="nearest")[0]
        thin = thin_parts(gt_all) if self.spec.thin > 0 and len(gt_all) else None
        coeffs = coeffs.float().transpose(1, 2)  # [B, A, nm]
        scale = torch.tensor(
            [gt_all.shape[2] / input_hw[1], gt_all.shape[1] / input_hw[0]] * 2,
            device=proto.device,
        )
        per_image = self._on_grid if self.spec.resolution == "proto" else self._upsampled
        total = proto.new_zeros(())
        # unbind once: indexing proto[i] per image would make every backward step allocate and
        # zero-fill a gradient the size of the whole batch's prototypes
        protos, coeff_rows = proto.unbind(0), coeffs.unbind(0)
        for i in range(proto.shape[0]):  # per image: the fg anchors of one image
            sel = assigned.fg[i]
            if not sel.any():
                continue
            gt_rows = rows[i].gather(0, assigned.gt_index[i][sel])  # [n] rows of ``masks``
            boxes = assigned.boxes[i][sel] * scale  # target pixels
            total = total + per_image(protos[i], coeff_rows[i][sel], gt_all, thin, gt_rows, boxes)
        return total / assigned.fg.sum()

    def _terms(
        self,
        logits: torch.Tensor,
        gt: torch.Tensor,
        weight: torch.Tensor | None,
        area: torch.Tensor,
    ) -> torch.Tensor:
        """``logits, gt [n, P]``, ``weight`` broadcastable to them (zero outside the box where
        the caller passes whole maps), ``area [n]`` or a scalar → ``[n]`` per-anchor loss."""
        bce = F.binary_cross_entropy_with_logits(logits, gt, reduction="none")
        if weight is not None:
            bce = bce * weight
        loss = bce.sum(1) / area
        if self.spec.dice > 0:
            p = logits.sigmoid()
            dice = 1.0 - (2.0 * (p * gt).sum(1) + 1.0) / (p.sum(1) + gt.sum(1) + 1.0)
            loss = loss + self.spec.dice * dice
        return loss

    def _on_grid(
        self,
        proto: torch.Tensor,
        coeffs: torch.Tensor,
        gt_all: torch.Tensor,
        thin: torch.Tensor | None,
        gt_rows: torch.Tensor,
        boxes: torch.Tensor,
    ) -> torch.Tensor:
        """The reference form: every anchor's full ``[Hp, Wp]`` map, zeroed outside its box."""
        nm, ph, pw = proto.shape
        xs = torch.arange(pw, device=proto.device, dtype=torch.float32) + 0.5
        ys = torch.arange(ph, device=proto.device, dtype=torch.float32) + 0.5
        in_x = (xs[None] >= boxes[:, 0:1]) & (xs[None] < boxes[:, 2:3])
        in_y = (ys[None] >= boxes[:, 1:2]) & (ys[None] < boxes[:, 3:4])
        crop = (in_y[:, :, None] & in_x[:, None, :]).reshape(len(boxes), -1).float()
        logits = coeffs @ proto.reshape(nm, -1)  # [n, Hp·Wp]
        gt = gt_all[gt_rows].reshape(len(boxes), -1)
        weight = crop if thin is None else crop * (1.0 + self.spec.thin * thin[gt_rows].flatten(1))
        area = ((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])).clamp(min=1.0)
        if self.spec.dice > 0:  # the Dice sums run over the box only
            logits = torch.where(crop > 0, logits, torch.full_like(logits, -1e4))
            gt = gt * crop
        return self._terms(logits, gt, weight, area).sum()

    def _upsampled(
        self,
        proto: torch.Tensor,
        coeffs: torch.Tensor,
        gt_all: torch.Tensor,
        thin: torch.Tensor | None,
        gt_rows: torch.Tensor,
        boxes: torch.Tensor,
    ) -> torch.Tensor:
        """Prototypes upsampled to the ground truth's size; one box window per instance."""
        nm = proto.shape[0]
        hm, wm = gt_all.shape[1:]
        up = F.interpolate(proto[None], (hm, wm), mode="bilinear", align_corners=False)[0]
        uniq, inverse = torch.unique(gt_rows, return_inverse=True)
        first = torch.zeros(len(uniq), dtype=torch.long, device=boxes.device)
        first.scatter_(0, inverse, torch.arange(len(inverse), device=boxes.device))
        total = proto.new_zeros(())
        for j, (row, box) in enumerate(zip(uniq.tolist(), boxes[first].tolist(), strict=True)):
            r0, r1, c0, c1 = box_pixel_bounds(box, hm, wm)
            if r1 <= r0 or c1 <= c0:
                continue
            k = inverse == j
            window = up[:, r0:r1, c0:c1].reshape(nm, -1)
            logits = coeffs[k] @ window  # [n_k, h·w]
            gt = gt_all[row, r0:r1, c0:c1].reshape(1, -1).expand_as(logits)
            weight = None
            if thin is not None:
                weight = 1.0 + self.spec.thin * thin[row, r0:r1, c0:c1].reshape(1, -1)
            area = torch.tensor(max((box[2] - box[0]) * (box[3] - box[1]), 1.0), device=up.device)
            total = total + self._terms(logits, gt, weight, area).sum()
        return total
