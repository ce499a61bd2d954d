"""Semantic logits → class maps on the network input or on the source frame.

A class map is ``[H, W]`` with ``0`` = background and ``k + 1`` = dataset class ``k``;
:data:`IGNORE_INDEX` marks pixels no metric or loss looks at (the letterbox padding of
validation images): its one home, used by the data targets, the loss and the metrics.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from slimseg.ops.letterbox import LetterboxParams

IGNORE_INDEX = 255


def logits_to_frame(
    logits: torch.Tensor, p: LetterboxParams, frame_hw: tuple[int, int]
) -> torch.Tensor:
    """One image's logits ``[K+1, H, W]`` at the network input → ``int64 [h, w]`` class map
    on the source frame: crop the letterbox content, resize the logits bilinearly
    (half-pixel centres) to ``h × w``, argmax over classes."""
    crop = logits[:, p.top : p.top + p.new_h, p.left : p.left + p.new_w].float()
    h, w = frame_hw
    if crop.shape[1:] != (h, w):
        crop = F.interpolate(crop[None], size=(h, w), mode="bilinear", align_corners=False)[0]
    return crop.argmax(dim=0)
