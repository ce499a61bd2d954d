"""Augmentation settings (YAML) and the albumentations pipelines built from them.

Boxes are never transformed directly: every geometric transform is applied to the image and
the instance masks, and boxes are recomputed from the transformed visible masks, so a box
always encloses exactly its mask. Instances left with fewer than ``min_area`` pixels are
dropped (and counted in ``Sample.meta["dropped_small"]``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import albumentations as A
import cv2
import numpy as np

from slimseg.data.sample import Sample
from slimseg.ops.letterbox import PAD_VALUE, letterbox_image, letterbox_mask, letterbox_params
from slimseg.utils.shipped import resolve_config
from slimseg.utils.strict_dataclass import dataclass_from_mapping
from slimseg.utils.yaml_io import read_yaml


@dataclass(frozen=True)
class AugmentConfig:
    """Training augmentation (YOLOv8 recipe defaults). Validation always = letterbox only."""

    mosaic: float = 1.0  # probability of a 4-image mosaic
    hsv_h: float = 0.015  # hue gain (fraction of the hue circle)
    hsv_s: float = 0.7  # saturation gain
    hsv_v: float = 0.4  # value gain
    fliplr: float = 0.5  # horizontal flip probability
    translate: float = 0.1  # ± fraction of the image size
    scale: float = 0.5  # scale gain: zoom in [1 − scale, 1 + scale]
    min_area: int = 4  # instances with fewer visible pixels after augmentation are dropped


def load_augment_config(path: str | Path | None) -> AugmentConfig:
    """Read an augmentation YAML (None → defaults)."""
    if path is None:
        return AugmentConfig()
    path = resolve_config(path, "data", "augmentation config")
    data = read_yaml(path, "augmentation config") or {}
    return dataclass_from_mapping(AugmentConfig, data, str(path))


class Letterbox(A.DualTransform):
    """albumentations wrapper around ``slimseg.ops.letterbox`` (the shared rule)."""

    def __init__(self, height: int, width: int, p: float = 1.0) -> None:
        super().__init__(p=p)
        self.height, self.width = height, width

    def get_params_dependent_on_data(self, params: dict, data: dict) -> dict:
        h, w = params["shape"][:2]
        return {"lb": letterbox_params(h, w, self.height, self.width)}

    def apply(self, img: np.ndarray, lb: Any = None, **params: Any) -> np.ndarray:
        return letterbox_image(img, lb)

    def apply_to_mask(self, mask: np.ndarray, lb: Any = None, **params: Any) -> np.ndarray:
        return letterbox_mask(mask, lb)

    def get_transform_init_args_names(self) -> tuple[str, ...]:
        return ("height", "width")


class RandomHSVGain(A.ImageOnlyTransform):
    """Multiply hue, saturation and value by random gains in ``1 ± (h, s, v)`` (YOLO style)."""

    def __init__(self, h: float, s: float, v: float, p: float = 1.0) -> None:
        super().__init__(p=p)
        self.gains = (h, s, v)

    def get_params(self) -> dict:
        return {"r": self.random_generator.uniform(-1, 1, 3) * np.array(self.gains) + 1}

    def apply(self, img: np.ndarray, r: Any = None, **params: Any) -> np.ndarray:
        hue, sat, val = cv2.split(cv2.cvtColor(img, cv2.COLOR_RGB2HSV))
        x = np.arange(256, dtype=np.float32)
        lut_h = ((x * r[0]) % 180).astype(np.uint8)
        lut_s = np.clip(x * r[1], 0, 255).astype(np.uint8)
        lut_v = np.clip(x * r[2], 0, 255).astype(np.uint8)
        hsv = cv2.merge((cv2.LUT(hue, lut_h), cv2.LUT(sat, lut_s), cv2.LUT(val, lut_v)))
        return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)

    def get_transform_init_args_names(self) -> tuple[str, ...]:
        return ("gains",)


def build_transform(cfg: AugmentConfig, imgsz: int, train: bool) -> A.Compose:
    """Letterbox to ``imgsz`` (+ affine, HSV, flip when ``train``) on image and masks."""
    steps: list[A.BasicTransform] = [Letterbox(imgsz, imgsz)]
    if train:
        steps += [
            A.Affine(
                scale=(1 - cfg.scale, 1 + cfg.scale),
                translate_percent=(-cfg.translate, cfg.translate),
                border_mode=cv2.BORDER_CONSTANT,
                fill=PAD_VALUE,
                fill_mask=0,
                p=1.0 if (cfg.scale or cfg.translate) else 0.0,
            ),
            RandomHSVGain(cfg.hsv_h, cfg.hsv_s, cfg.hsv_v),
            A.HorizontalFlip(p=cfg.fliplr),
        ]
    return A.Compose(steps, seed=None)


def masks_to_boxes(masks: np.ndarray) -> np.ndarray:
    """``uint8 [N, H, W]`` → xyxy ``float32 [N, 4]`` (pixel edges: x2 = last column + 1)."""
    n = len(masks)
    boxes = np.zeros((n, 4), np.float32)
    if n == 0:
        return boxes
    cols, rows = masks.any(axis=1), masks.any(axis=2)
    for i in range(n):
        xs, ys = np.flatnonzero(cols[i]), np.flatnonzero(rows[i])
        if len(xs):
            boxes[i] = (xs[0], ys[0], xs[-1] + 1, ys[-1] + 1)
    return boxes


def pack_masks(masks: np.ndarray) -> np.ndarray:
    """0/1 ``uint8 [N, H, W]`` → ``uint8 [H, W, ceil(N / 8)]``, 8 masks per byte (mask ``k`` in
    bit ``k % 8`` of channel ``k // 8``; at least one channel)."""
    n, h, w = masks.shape
    planes = np.zeros((max(1, -(-n // 8)), h, w), np.uint8)
    shifted = np.empty((h, w), np.uint8)
    for k in range(n):  # one contiguous pass per mask (numpy's packbits across masks is slow)
        np.left_shift(masks[k], k % 8, out=shifted)
        planes[k // 8] |= shifted
    return np.ascontiguousarray(planes.transpose(1, 2, 0))


def unpack_masks(packed: np.ndarray, n: int) -> np.ndarray:
    """Inverse of :func:`pack_masks`: ``uint8 [H, W, C]`` (or ``[H, W]``) → ``[n, H, W]``."""
    h, w = packed.shape[:2]
    planes = np.ascontiguousarray(packed.reshape(h, w, -1).transpose(2, 0, 1))
    out = np.empty((n, h, w), np.uint8)
    for k in range(n):
        np.right_shift(planes[k // 8], k % 8, out=out[k])
        out[k] &= 1
    return out


def apply_transform(transform: A.Compose, sample: Sample, min_area: int = 1) -> Sample:
    """Run ``transform`` on a sample's image and masks; recompute boxes; drop tiny instances.

    The masks travel bit-packed (:func:`pack_masks`, 8 per byte of a multi-channel mask):
    every geometric step maps masks by nearest-neighbour (each output pixel copies one source
    pixel, in every channel alike), so the bits come out exactly as if each mask had been
    transformed alone, at a fraction of the work."""
    out = transform(image=sample.image, mask=pack_masks(sample.masks))
    image = out["image"]
    new_masks = unpack_masks(out["mask"], len(sample.masks))
    # visible pixels per mask (masks are 0/1); count_nonzero per mask is ~5x a sum over axes
    visible = np.fromiter((np.count_nonzero(m) for m in new_masks), np.int64, len(new_masks))
    keep = visible >= max(min_area, 1)
    meta = dict(sample.meta)
    meta["dropped_small"] = meta.get("dropped_small", 0) + int((~keep).sum())
    new_masks = new_masks[keep]
    return Sample(
        image=image,
        boxes=masks_to_boxes(new_masks),
        classes=sample.classes[keep],
        masks=new_masks,
        image_id=sample.image_id,
        path=sample.path,
        meta=meta,
    )
