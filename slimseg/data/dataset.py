"""Training/validation view of an annotated dataset: mosaic, augmentation, letterbox."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from torch.utils.data import Dataset

from slimseg.data.augment import AugmentConfig, apply_transform, build_transform, masks_to_boxes
from slimseg.data.letterbox import letterbox_image, letterbox_mask, letterbox_params
from slimseg.data.mosaic import mosaic4
from slimseg.data.sample import Sample


class YoloDataset(Dataset):
    """Wraps a dataset of ``Sample`` and yields network-sized samples.

    Train (``augment`` given): mosaic with probability ``augment.mosaic`` (switch off with
    ``mosaic_enabled = False`` for the last epochs), then affine, HSV and flip. Validation
    (``augment=None``): the shared letterbox only; ``meta["letterbox"]`` and
    ``meta["orig_shape"]`` let predictions be mapped back to the source frame.
    """

    def __init__(
        self,
        base: Sequence[Sample],
        imgsz: int,
        augment: AugmentConfig | None = None,
        seed: int = 0,
    ) -> None:
        self.base = base
        self.imgsz = imgsz
        self.augment = augment
        self.seed = seed
        self.mosaic_enabled = augment is not None and augment.mosaic > 0
        self.transform = build_transform(augment, imgsz, train=True) if augment else None
        self.rng = np.random.default_rng(seed)
        if self.transform is not None:
            self.transform.set_random_seed(seed)

    def reseed(self, seed: int) -> None:
        """Re-seed augmentation (called per worker and per epoch for reproducibility)."""
        self.rng = np.random.default_rng(seed)
        if self.transform is not None:
            self.transform.set_random_seed(seed)

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, index: int) -> Sample:
        if self.augment is None:
            return self._letterbox(self.base[index])
        if self.mosaic_enabled and self.rng.random() < self.augment.mosaic:
            others = self.rng.integers(0, len(self.base), 3)
            sample = mosaic4(
                [self.base[index], *(self.base[int(i)] for i in others)], self.imgsz, self.rng
            )
        else:
            sample = self.base[index]
        return apply_transform(self.transform, sample, self.augment.min_area)

    def _letterbox(self, sample: Sample) -> Sample:
        h, w = sample.image.shape[:2]
        p = letterbox_params(h, w, self.imgsz, self.imgsz)
        masks = (
            np.stack([letterbox_mask(m, p) for m in sample.masks])
            if len(sample.masks)
            else np.zeros((0, self.imgsz, self.imgsz), np.uint8)
        )
        meta = dict(sample.meta, letterbox=p, orig_shape=(h, w))
        return Sample(
            image=letterbox_image(sample.image, p),
            boxes=masks_to_boxes(masks),
            classes=sample.classes,
            masks=masks,
            image_id=sample.image_id,
            path=sample.path,
            meta=meta,
        )
