"""Training/validation view of an annotated dataset: mosaic, augmentation, letterbox."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from torch.utils.data import Dataset

from slimseg.data.augment import AugmentConfig, apply_transform, build_transform, masks_to_boxes
from slimseg.data.letterbox import letterbox_image, letterbox_mask, letterbox_params
from slimseg.data.mosaic import mosaic4
from slimseg.data.sample import Sample

#: Decoded training images (and masks) a loader process keeps, in MiB: a mosaic sample reads
#: four source images, so a training set that fits is decoded once per process instead of about
#: four times per epoch (the samples are the same, only the decoding is saved).
TRAIN_CACHE_MIB = 1024


class YoloDataset(Dataset):
    """Wraps a dataset of ``Sample`` and yields network-sized samples.

    Train (``augment`` given): mosaic with probability ``augment.mosaic`` (switch off with
    ``mosaic_enabled = False`` for the last epochs), then affine, HSV and flip. Validation
    (``augment=None``): the shared letterbox only; ``meta["letterbox"]`` and
    ``meta["orig_shape"]`` let predictions be mapped back to the source frame.

    ``cache_mib``: decoded source samples kept in this process, up to that many MiB (first
    come, kept; arrays read-only), e.g. :data:`TRAIN_CACHE_MIB`; 0 = decode every time.
    """

    def __init__(
        self,
        base: Sequence[Sample],
        imgsz: int,
        augment: AugmentConfig | None = None,
        seed: int = 0,
        cache_mib: int = 0,
    ) -> None:
        self.base = base
        self.cache_bytes = cache_mib * 2**20
        self._cache: dict[int, Sample] = {}
        self._cached_bytes = 0
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

    def _source(self, index: int) -> Sample:
        """``base[index]``, from the cache when it holds it (and cached when it fits)."""
        hit = self._cache.get(index)
        if hit is not None:
            return hit
        sample = self.base[index]
        arrays = [sample.image, sample.masks, sample.boxes, sample.classes]
        size = sum(a.nbytes for a in arrays)
        if self._cached_bytes + size <= self.cache_bytes:
            for a in arrays:
                a.flags.writeable = False  # shared by every later use: never modified
            self._cache[index] = sample
            self._cached_bytes += size
        return sample

    def __getitem__(self, index: int) -> Sample:
        if self.augment is None:
            return self._letterbox(self.base[index])
        if self.mosaic_enabled and self.rng.random() < self.augment.mosaic:
            others = self.rng.integers(0, len(self.base), 3)
            sample = mosaic4(
                [self._source(index), *(self._source(int(i)) for i in others)],
                self.imgsz,
                self.rng,
            )
        else:
            sample = self._source(index)
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
