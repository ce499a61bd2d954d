"""Lightning DataModule: dataset config → seeded train/val loaders of loss-ready batches."""

from __future__ import annotations

from collections.abc import Iterator

import lightning as L
import torch
from torch.utils.data import DataLoader, Sampler, get_worker_info

from slimseg.data.augment import AugmentConfig
from slimseg.data.coco import CocoDataset
from slimseg.data.collate import make_collate
from slimseg.data.config import DataConfig
from slimseg.data.dataset import TRAIN_CACHE_MIB, YoloDataset, mosaic_buffer_size


class EpochSampler(Sampler[int]):
    """Shuffles with ``seed + epoch`` and re-seeds the dataset's augmentation per epoch.

    Lightning calls ``set_epoch`` before each training epoch, so the order and the augmentation
    of epoch ``e`` depend only on ``(seed, e)``: a resumed run sees the same batches as an
    uninterrupted one. ``generator`` is the DataLoader's (worker seeds are drawn from it); it is
    re-seeded per epoch too.
    """

    def __init__(self, dataset: YoloDataset, seed: int, generator: torch.Generator) -> None:
        self.dataset, self.seed, self.generator = dataset, seed, generator
        self.set_epoch(0)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch
        self.generator.manual_seed(self.seed + epoch)
        self.dataset.reseed(self.seed * 1_000_003 + epoch)

    def __len__(self) -> int:
        return len(self.dataset)

    def __iter__(self) -> Iterator[int]:
        # a private generator: the order must not depend on who else drew from the shared one
        order = torch.Generator().manual_seed(self.seed * 7919 + self.epoch)
        return iter(torch.randperm(len(self.dataset), generator=order).tolist())


def _seed_worker(_worker_id: int) -> None:
    """Each worker re-seeds its augmentation from torch's per-worker, per-epoch seed."""
    info = get_worker_info()
    if info is not None and isinstance(info.dataset, YoloDataset):
        info.dataset.reseed(torch.initial_seed() % 2**32)


class SegDataModule(L.LightningDataModule):
    """Train/val loaders for a dataset config (see ``slimseg.data.config``).

    Batches are dicts from ``slimseg.data.collate.make_collate``. Workers are re-created every
    epoch (not persistent) so the trainer's ``mosaic_enabled`` switch reaches them.
    """

    def __init__(
        self,
        data: DataConfig,
        imgsz: int = 320,
        batch_size: int = 8,
        workers: int = 2,
        augment: AugmentConfig | None = None,
        seed: int = 0,
        mask_ratio: int = 4,
        semantic: bool = False,
    ) -> None:
        super().__init__()
        self.data = data
        self.imgsz, self.batch_size, self.workers = imgsz, batch_size, workers
        self.augment = augment or AugmentConfig()
        self.seed, self.mask_ratio = seed, mask_ratio
        self.semantic = semantic  # batches carry class-map targets (semantic models)
        self.train_set: YoloDataset | None = None
        self.val_set: YoloDataset | None = None

    def _base(self, split: str) -> CocoDataset:
        # depth maps are not a training target: skip reading them (40% of the decode time)
        s = self.data.split(split)
        return CocoDataset(s.images, s.annotations, names=self.data.names)

    def setup(self, stage: str | None = None) -> None:
        if stage in (None, "fit") and self.train_set is None:
            self.train_set = YoloDataset(
                self._base("train"),
                self.imgsz,
                self.augment,
                self.seed,
                TRAIN_CACHE_MIB,
                mosaic_buffer_size(self.batch_size),
            )
        if self.val_set is None:
            self.val_set = YoloDataset(self._base("val"), self.imgsz)

    def _loader(self, dataset: YoloDataset, shuffle: bool) -> DataLoader:
        generator = torch.Generator().manual_seed(self.seed)
        return DataLoader(
            dataset,
            batch_size=self.batch_size,
            sampler=EpochSampler(dataset, self.seed, generator) if shuffle else None,
            num_workers=self.workers,
            collate_fn=make_collate(self.mask_ratio, self.semantic),
            pin_memory=torch.cuda.is_available(),
            worker_init_fn=_seed_worker,
            generator=generator,
        )

    def transfer_batch_to_device(self, batch: dict, device: torch.device, idx: int) -> dict:
        """Move the tensors; ``meta`` (letterbox geometry, paths) stays on the host."""
        return {k: v.to(device) if torch.is_tensor(v) else v for k, v in batch.items()}

    def train_dataloader(self) -> DataLoader:
        assert self.train_set is not None, "call setup('fit') first"
        return self._loader(self.train_set, shuffle=True)

    def val_dataloader(self) -> DataLoader:
        assert self.val_set is not None, "call setup() first"
        return self._loader(self.val_set, shuffle=False)
