"""MSNET's loss: per-pixel cross-entropy plus soft multi-class dice.

``loss = ce_weight · CE + dice_weight · dice`` with ``CE`` the mean over labelled pixels and
``dice = 1 − mean_k 2|P_k ∩ G_k| / (|P_k| + |G_k|)`` over the classes present in the batch's
ground truth (softmax probabilities ``P``, one-hot targets ``G``, pixels with
``IGNORE_INDEX`` left out of both). Weights 1 : 1: cross-entropy drives every pixel, dice
counters the background's majority (small objects such as sports balls).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from slimseg.ops.semantic import IGNORE_INDEX


class SemanticLoss(nn.Module):
    """``(logits [B, K+1, H, W], target int64 [B, H, W]) → (loss, {"ce", "dice"})``.

    The returned loss is multiplied by the batch size (the Lightning module divides the
    logged value by it, as for the YOLO losses).
    """

    def __init__(self, ce_weight: float = 1.0, dice_weight: float = 1.0, eps: float = 1.0) -> None:
        super().__init__()
        self.ce_weight, self.dice_weight, self.eps = ce_weight, dice_weight, eps

    def forward(
        self, logits: torch.Tensor, target: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        if logits.shape[2:] != target.shape[1:]:
            logits = F.interpolate(
                logits, size=target.shape[1:], mode="bilinear", align_corners=False
            )
        target = target.long()
        ce = F.cross_entropy(logits, target, ignore_index=IGNORE_INDEX)
        valid = target != IGNORE_INDEX
        k = logits.shape[1]
        prob = logits.float().softmax(dim=1) * valid.unsqueeze(1)
        onehot = F.one_hot(target.clamp(max=k - 1) * valid, k).permute(0, 3, 1, 2)
        onehot = onehot * valid.unsqueeze(1)
        inter = (prob * onehot).sum(dim=(0, 2, 3))
        denom = prob.sum(dim=(0, 2, 3)) + onehot.sum(dim=(0, 2, 3))
        present = onehot.sum(dim=(0, 2, 3)) > 0
        dice_k = 1 - (2 * inter + self.eps) / (denom + self.eps)
        dice = dice_k[present].mean() if present.any() else logits.sum() * 0
        if not torch.isfinite(ce):  # every pixel ignored
            ce = logits.sum() * 0
        loss = self.ce_weight * ce + self.dice_weight * dice
        bs = logits.shape[0]
        return loss * bs, {"ce": ce.detach(), "dice": dice.detach()}
