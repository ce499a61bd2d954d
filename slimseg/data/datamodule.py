"""Lightning DataModule: dataset config → seeded train/val loaders of loss-ready batches."""

from __future__ import annotations

from collections.abc import Iterator

import lightning as L
import torch
from torch.utils.data import DataLoader, Sampler

from slimseg.data.augment import AugmentConfig
from slimseg.data.coco import CocoDataset
from slimseg.data.collate import make_collate
from slimseg.data.config import DataConfig
from slimseg.data.dataset import TRAIN_CACHE_MIB, EpochIndex, ZooDataset, mosaic_buffer_size


class EpochSampler(Sampler[EpochIndex]):
    """Shuffles with ``seed + epoch``; each index carries the epoch and its mosaic switch.

    Lightning calls ``set_epoch`` before each training epoch; the dataset re-seeds its
    augmentation from ``(seed, epoch, loader worker, DDP rank)`` when the first index of an
    epoch reaches it (:class:`~slimseg.data.dataset.EpochIndex`), in whichever process loads
    it. So the
    order and the augmentation of epoch ``e`` depend only on ``(seed, e)`` and the worker
    count, a resumed run sees the same batches as an uninterrupted one, and persistent loader
    workers (which never see the main process' dataset again) follow the epoch and the
    mosaic switch, on for the first ``mosaic_epochs`` epochs (``None``: all). ``generator`` is
    the DataLoader's; it is re-seeded per epoch too.
    """

    def __init__(
        self,
        dataset: ZooDataset,
        seed: int,
        generator: torch.Generator,
        mosaic_epochs: int | None = None,
    ) -> None:
        self.dataset, self.seed, self.generator = dataset, seed, generator
        self.mosaic_epochs = mosaic_epochs
        self.set_epoch(0)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch
        self.generator.manual_seed(self.seed + epoch)

    def __len__(self) -> int:
        return len(self.dataset)

    def __iter__(self) -> Iterator[EpochIndex]:
        # a private generator: the order must not depend on who else drew from the shared one
        order = torch.Generator().manual_seed(self.seed * 7919 + self.epoch)
        mosaic = self.mosaic_epochs is None or self.epoch < self.mosaic_epochs
        for i in torch.randperm(len(self.dataset), generator=order).tolist():
            yield EpochIndex(i, self.epoch, mosaic)


class SegDataModule(L.LightningDataModule):
    """Train/val loaders for a dataset config (see ``slimseg.data.config``).

    Batches are dicts from ``slimseg.data.collate.make_collate``. Loader workers are
    persistent (started once per fit, their decoded-sample caches kept across epochs): the
    epoch's seed and mosaic switch reach them with each index (:class:`EpochSampler`).
    ``mosaic_epochs``: epochs that use mosaic, from the first (``None``: all; training passes
    ``epochs - close_mosaic``).
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
        mosaic_epochs: int | None = None,
    ) -> None:
        super().__init__()
        self.mosaic_epochs = mosaic_epochs
        self.data = data
        self.imgsz, self.batch_size, self.workers = imgsz, batch_size, workers
        self.augment = augment or AugmentConfig()
        self.seed, self.mask_ratio = seed, mask_ratio
        self.semantic = semantic  # batches carry class-map targets (semantic models)
        self.train_set: ZooDataset | None = None
        self.val_set: ZooDataset | None = None

    def _base(self, split: str) -> CocoDataset:
        # depth maps are not a training target: skip reading them (40% of the decode time)
        return CocoDataset.from_config(self.data, split, depth=False)

    def setup(self, stage: str | None = None) -> None:
        if stage in (None, "fit") and self.train_set is None:
            self.train_set = ZooDataset(
                self._base("train"),
                self.imgsz,
                self.augment,
                self.seed,
                TRAIN_CACHE_MIB,
                mosaic_buffer_size(self.batch_size),
                rank=0 if self.trainer is None else self.trainer.global_rank,
            )
        if self.val_set is None:
            self.val_set = ZooDataset(self._base("val"), self.imgsz)

    def _loader(self, dataset: ZooDataset, shuffle: bool) -> DataLoader:
        generator = torch.Generator().manual_seed(self.seed)
        sampler = None
        if shuffle:
            sampler = EpochSampler(dataset, self.seed, generator, self.mosaic_epochs)
            # Lightning creates the first epoch's iterator (whose workers fetch ahead) before it
            # calls set_epoch: start at the epoch it will pass (a run resumed from an end-of-
            # epoch checkpoint has processed that epoch, not yet completed it), or a resumed run
            # would load epoch 0's batches for its first epoch
            trainer = self.trainer
            sampler.set_epoch(
                0 if trainer is None else trainer.fit_loop.epoch_progress.current.processed
            )
        return DataLoader(
            dataset,
            batch_size=self.batch_size,
            sampler=sampler,
            num_workers=self.workers,
            collate_fn=make_collate(self.mask_ratio, self.semantic),
            pin_memory=torch.cuda.is_available(),
            persistent_workers=self.workers > 0,
            generator=generator,
        )

    def transfer_batch_to_device(self, batch: dict, device: torch.device, idx: int) -> dict:
        """Move the tensors; ``meta`` (letterbox geometry, paths) stays on the host."""
        # non_blocking: with pinned host memory (pin_memory on CUDA) the copy overlaps compute
        return {
            k: v.to(device, non_blocking=True) if torch.is_tensor(v) else v
            for k, v in batch.items()
        }

    def train_dataloader(self) -> DataLoader:
        assert self.train_set is not None, "call setup('fit') first"
        return self._loader(self.train_set, shuffle=True)

    def val_dataloader(self) -> DataLoader:
        assert self.val_set is not None, "call setup() first"
        return self._loader(self.val_set, shuffle=False)
