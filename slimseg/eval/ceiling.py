"""The mask-resolution ceiling: ground-truth masks pushed through a ``ratio`` times coarser
grid and back, as "detections" (score 1, ground-truth class) to score with
:func:`~slimseg.eval.mask_quality.mask_quality`: the best any model whose masks live on
that grid can do.

Down: :func:`slimseg.data.collate.downsample_masks` (the training targets' rule: a cell is
set when at least half of its ``ratio × ratio`` block is), after zero-padding the frame
bottom/right to a multiple of ``ratio``. Up: :func:`slimseg.ops.masks.assemble_masks`
itself (the predictor's rule: bilinear with half-pixel centres, crop to the box, ``> 0.5``),
fed one prototype per instance, ``±1`` for set/unset cells, and coefficients ``GAIN × I``:
``sigmoid(±GAIN)`` is symmetric about 0.5, so thresholding the interpolated probabilities
at 0.5 is thresholding the interpolated 0/1 map at 0.5. The box is the mask's own tight box
(a perfect box). Frames are taken as the network input (no letterbox scale): exact for
frames of the training size, like the synthetic sets. Crowd ground truth gives no
detection.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO

from slimseg.data.collate import downsample_masks
from slimseg.detections import decode_rle, encode_rle
from slimseg.eval.coco_eval import load_gt
from slimseg.ops.masks import assemble_masks

#: Coefficient scale of the ceiling's prototypes (sigmoid(8) = 0.99966).
GAIN = 8.0


def coarse_masks(masks: np.ndarray, ratio: int, boxes: np.ndarray | None = None) -> np.ndarray:
    """``bool [N, H, W]`` → ``bool [N, H, W]``: each mask down to the ``ratio``-coarser grid
    and back up (module docstring). ``boxes``: ``float [N, 4]`` xyxy crop boxes (default:
    each mask's tight box); ``ratio = 1`` returns the masks cropped to the boxes."""
    if masks.ndim != 3:
        raise ValueError(f"expected masks [N, H, W], got shape {masks.shape}")
    if ratio < 1:
        raise ValueError(f"ratio must be >= 1, got {ratio}")
    n, h, w = masks.shape
    if n == 0:
        return masks.astype(bool, copy=True)
    if boxes is None:
        xywh = mask_utils.toBbox(encode_rle(masks)).reshape(n, 4)
        boxes = np.concatenate([xywh[:, :2], xywh[:, :2] + xywh[:, 2:]], axis=1)
    hp, wp = -(-h // ratio) * ratio, -(-w // ratio) * ratio
    padded = np.zeros((n, hp, wp), np.uint8)
    padded[:, :h, :w] = masks
    cells = downsample_masks(padded, ratio)  # uint8 [N, hp / r, wp / r]
    proto = torch.from_numpy(cells).float() * 2 - 1
    coeffs = torch.eye(n) * GAIN
    up = assemble_masks(coeffs, proto, torch.as_tensor(boxes, dtype=torch.float32), (hp, wp))
    return up[:, :h, :w].numpy()


def ceiling_detections(
    coco_gt: str | Path | dict | COCO, ratio: int = 4, image_ids: Sequence[int] | None = None
) -> list[dict]:
    """COCO result dicts (RLE ``segmentation``, ``score`` 1.0, the ground truth's
    ``category_id``): every non-crowd ground-truth mask of ``image_ids`` (default: all)
    through :func:`coarse_masks` at ``ratio``."""
    gt = load_gt(coco_gt)
    imgs = sorted(gt.imgs) if image_ids is None else sorted(int(i) for i in image_ids)
    out: list[dict] = []
    for img in imgs:
        if img not in gt.imgs:
            raise ValueError(f"image id {img} is not in the ground truth")
        info = gt.imgs[img]
        anns = [a for a in gt.imgToAnns.get(img, []) if not a.get("iscrowd", 0)]
        if not anns:
            continue
        masks = decode_rle([gt.annToRLE(a) for a in anns], (info["height"], info["width"]))
        rles = encode_rle(coarse_masks(masks, ratio))
        out += [
            {"image_id": img, "category_id": a["category_id"], "segmentation": r, "score": 1.0}
            for a, r in zip(anns, rles, strict=True)
        ]
    return out
