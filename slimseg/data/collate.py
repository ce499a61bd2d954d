"""Batching: samples → the tensors the YOLOv8-seg loss consumes."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
import torch

from slimseg.data.sample import Sample
from slimseg.data.semantic import ignore_padding, semantic_target


def downsample_masks(masks: np.ndarray, ratio: int) -> np.ndarray:
    """``uint8 [N, H, W]`` → ``uint8 [N, H/r, W/r]``: 1 where ≥ half of the r×r block is set."""
    n, h, w = masks.shape
    if ratio == 1:
        return masks
    area = ratio * ratio
    if area > 255:
        raise ValueError(f"mask ratio {ratio} is too large (at most 15)")
    # OpenCV's area resize at an integer ratio is the block sum times 1/area, rounded: with the
    # mask scaled to 0/area that is the block's pixel count, exactly (2-3x numpy's block sums)
    scaled = np.empty((h, w), np.uint8)
    out = np.empty((n, h // ratio, w // ratio), np.uint8)
    for i in range(n):
        np.multiply(masks[i], area, out=scaled, casting="unsafe")
        cv2.resize(scaled, (w // ratio, h // ratio), out[i], interpolation=cv2.INTER_AREA)
    # mean >= 0.5  <=>  2 * count >= area
    return (out >= (area + 1) // 2).astype(np.uint8)


def network_input(images: torch.Tensor, device: torch.device | str | None = None) -> torch.Tensor:
    """Batch images ``uint8 [B, 3, H, W]`` → the network's input, ``float32 [B, 3, H, W]`` in
    [0, 1], on ``device`` (default: where the images are).

    The conversion happens after the transfer, so a loader worker and the host-to-device copy
    handle a quarter of the bytes; the result is contiguous NCHW (the memory format the
    network is timed and trained in on the CPU).
    """
    if images.dtype != torch.uint8:
        raise TypeError(f"expected uint8 batch images, got {images.dtype}")
    x = images.to(device, non_blocking=True) if device is not None else images
    return x.contiguous().float().div_(255.0)


def make_collate(mask_ratio: int = 4, semantic: bool = False) -> Callable[[list[Sample]], dict]:
    """Collate function producing a batch dict.

    ``images``: ``uint8 [B, 3, H, W]`` RGB, contiguous (:func:`network_input` makes the
    network's float input of them, after the transfer to the device); ``targets``:
    ``float32 [M, 6]`` rows ``(batch_index, class, x1, y1, x2, y2)`` in input pixels;
    ``masks``: ``uint8 [M, H/r, W/r]`` aligned with ``targets``; plus ``image_ids``,
    ``paths``, ``meta``. With ``semantic=True`` (semantic models) also ``semantic``:
    ``int64 [B, H, W]`` class maps (0 = background, class + 1, later instances painted over
    earlier ones; letterbox padding of validation samples = ``IGNORE_INDEX``).
    """

    def collate(samples: list[Sample]) -> dict:
        h, w = samples[0].image.shape[:2]
        stacked = np.empty((len(samples), 3, h, w), np.uint8)  # HWC -> CHW: one uint8 copy
        for i, s in enumerate(samples):
            stacked[i] = s.image.transpose(2, 0, 1)
        images = torch.from_numpy(stacked)
        rows, masks, class_maps = [], [], []
        for i, s in enumerate(samples):
            if semantic:
                target = semantic_target(s.masks, s.classes)
                if "letterbox" in s.meta:
                    target = ignore_padding(target, s.meta["letterbox"])
                class_maps.append(target)
            n = s.num_instances
            if n == 0:
                continue
            idx = np.full((n, 1), i, np.float32)
            rows.append(np.concatenate([idx, s.classes[:, None].astype(np.float32), s.boxes], 1))
            masks.append(downsample_masks(s.masks, mask_ratio))
        return {
            "images": images,
            "targets": torch.from_numpy(np.concatenate(rows)) if rows else torch.zeros(0, 6),
            "masks": torch.from_numpy(np.concatenate(masks))
            if masks
            else torch.zeros(0, h // mask_ratio, w // mask_ratio, dtype=torch.uint8),
            **({"semantic": torch.from_numpy(np.stack(class_maps))} if semantic else {}),
            "image_ids": [s.image_id for s in samples],
            "paths": [s.path for s in samples],
            "meta": [s.meta for s in samples],
        }

    return collate
