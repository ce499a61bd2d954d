"""Training/validation view of an annotated dataset: mosaic, augmentation, letterbox."""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from torch.utils.data import Dataset, get_worker_info

from slimseg.data.augment import AugmentConfig, apply_transform, build_transform, masks_to_boxes
from slimseg.data.mosaic import mosaic4
from slimseg.data.sample import Sample
from slimseg.ops.letterbox import letterbox_image, letterbox_mask, letterbox_params

#: Decoded training images (and masks) a loader process keeps, in MiB: a training set that fits
#: is decoded once per process (persistent workers keep it across epochs) instead of once per
#: epoch and sample (the samples are the same, only the decoding is saved).
TRAIN_CACHE_MIB = 1024

#: Mosaic partners are drawn from the most recently decoded source samples, as in the
#: reference implementation: at most this many batches' worth (of the loader's batch size) ...
MOSAIC_BUFFER_BATCHES = 8
#: ... and at most this many samples (and never more than the dataset holds) ...
MOSAIC_BUFFER_MAX = 1000
#: ... and at most this many MiB of decoded images and masks per loader process.
MOSAIC_BUFFER_MIB = 512


def mosaic_buffer_size(batch: int) -> int:
    """Recently decoded samples a training loader keeps as mosaic partners (the reference's
    rule: 8 batches, at most 1000)."""
    return min(MOSAIC_BUFFER_BATCHES * max(batch, 1), MOSAIC_BUFFER_MAX)


class EpochIndex(NamedTuple):
    """A training-sample request that carries its epoch's state to whichever process loads it
    (a persistent loader worker never sees the main process' dataset object again)."""

    index: int
    epoch: int
    mosaic: bool  # whether this epoch uses mosaic (off for the closing epochs)


def _nbytes(sample: Sample) -> int:
    return sum(a.nbytes for a in (sample.image, sample.masks, sample.boxes, sample.classes))


class ZooDataset(Dataset):
    """Wraps a dataset of ``Sample`` and yields network-sized samples.

    Train (``augment`` given): mosaic with probability ``augment.mosaic`` (switch off with
    ``mosaic_enabled = False`` for the last epochs), then affine, HSV and flip. Validation
    (``augment=None``): the shared letterbox only; ``meta["letterbox"]`` and
    ``meta["orig_shape"]`` let predictions be mapped back to the source frame.

    ``cache_mib``: decoded source samples kept in this process, up to that many MiB (first
    come, kept; arrays read-only), e.g. :data:`TRAIN_CACHE_MIB`; 0 = decode every time.

    Mosaic partners: the sample asked for is decoded and joins a buffer of the last
    ``mosaic_buffer`` decoded samples (default ``mosaic_buffer_size(8)``; capped at the
    dataset's size and at :data:`MOSAIC_BUFFER_MIB`); its three partners are drawn uniformly
    from that buffer, so a mosaic costs one decode instead of four (the reference
    implementation's scheme, :func:`mosaic_buffer_size`). While the buffer is
    still filling (the first few samples after :meth:`reseed`), partners are drawn from the
    whole dataset and join the buffer too. :meth:`reseed` empties it, so the samples of an
    epoch depend only on the seed (resume sees the same batches).

    Indices may be :class:`EpochIndex` (what the training sampler yields): the first one of a
    new epoch re-seeds the process that loads it with :meth:`epoch_seed` (seed, epoch, loader
    worker, ``rank``), and each says whether its epoch uses mosaic (``mosaic_enabled`` and it
    must both be true), so persistent workers follow both.

    ``rank``: the global rank of the training process (DDP): each rank draws its own
    augmentation stream (flips, affines, HSV gains, mosaic partners); rank 0's is the stream
    of a single-process run.
    """

    def __init__(
        self,
        base: Sequence[Sample],
        imgsz: int,
        augment: AugmentConfig | None = None,
        seed: int = 0,
        cache_mib: int = 0,
        mosaic_buffer: int = MOSAIC_BUFFER_BATCHES * 8,
        rank: int = 0,
    ) -> None:
        self.base = base
        self.rank = rank
        self.cache_bytes = cache_mib * 2**20
        self._cache: dict[int, Sample] = {}
        self._cached_bytes = 0
        self.buffer_size = max(1, min(mosaic_buffer, len(base)))
        self._recent: OrderedDict[int, Sample] = OrderedDict()
        self._recent_bytes = 0
        self._buffer_full = False
        self._epoch: int | None = None  # the epoch of the last EpochIndex request
        self.imgsz = imgsz
        self.augment = augment
        self.seed = seed
        self.mosaic_enabled = augment is not None and augment.mosaic > 0
        self.transform = build_transform(augment, imgsz, train=True) if augment else None
        self.rng = np.random.default_rng(seed)
        if self.transform is not None:
            self.transform.set_random_seed(seed)

    def epoch_seed(self, epoch: int, worker: int) -> int:
        """The augmentation seed of ``epoch`` in loader worker ``worker`` (0: main process) of
        this dataset's ``rank``. Rank 0 keeps the seed a single-process run has always had, so
        a one-device run draws the same stream as before ranks were part of it."""
        entropy = [self.seed, epoch, worker] + ([self.rank] if self.rank else [])
        return int(np.random.SeedSequence(entropy).generate_state(1)[0])

    def reseed(self, seed: int) -> None:
        """Re-seed augmentation (called per worker and per epoch for reproducibility)."""
        self.rng = np.random.default_rng(seed)
        if self.transform is not None:
            self.transform.set_random_seed(seed)
        self._recent.clear()
        self._recent_bytes, self._buffer_full = 0, False

    def __len__(self) -> int:
        return len(self.base)

    def _source(self, index: int) -> Sample:
        """``base[index]``, from the cache when it holds it (and cached when it fits)."""
        hit = self._cache.get(index)
        if hit is not None:
            return hit
        sample = self.base[index]
        size = _nbytes(sample)
        if self._cached_bytes + size <= self.cache_bytes:
            for a in (sample.image, sample.masks, sample.boxes, sample.classes):
                a.flags.writeable = False  # shared by every later use: never modified
            self._cache[index] = sample
            self._cached_bytes += size
        return sample

    def __getitem__(self, index: int | EpochIndex) -> Sample:
        if isinstance(index, EpochIndex):  # the first request of an epoch re-seeds this process
            if index.epoch != self._epoch:
                worker = get_worker_info()
                self.reseed(self.epoch_seed(index.epoch, 0 if worker is None else worker.id))
                self._epoch = index.epoch
            mosaic, index = self.mosaic_enabled and index.mosaic, index.index
        else:
            mosaic = self.mosaic_enabled
        if self.augment is None:
            return self._letterbox(self.base[index])
        if mosaic and self.rng.random() < self.augment.mosaic:
            sample = mosaic4(self.mosaic_sources(index), self.imgsz, self.rng)
        else:
            sample = self._source(index)
        return apply_transform(self.transform, sample, self.augment.min_area)

    def _buffered(self, index: int) -> Sample:
        """``base[index]`` (decoded or cached), now the newest entry of the partner buffer."""
        sample = self._recent.pop(index, None)
        if sample is None:
            sample = self._source(index)
        else:
            self._recent_bytes -= _nbytes(sample)
        for a in (sample.image, sample.masks):
            a.flags.writeable = False  # a partner of later mosaics: never modified
        self._recent[index] = sample
        self._recent_bytes += _nbytes(sample)
        cap = MOSAIC_BUFFER_MIB * 2**20
        while len(self._recent) > self.buffer_size or (
            self._recent_bytes > cap and len(self._recent) > 1
        ):
            self._recent_bytes -= _nbytes(self._recent.popitem(last=False)[1])
            self._buffer_full = True
        self._buffer_full |= len(self._recent) == self.buffer_size
        return sample

    def mosaic_sources(self, index: int) -> list[Sample]:
        """The decoded sample ``index`` and its three mosaic partners, the inputs of one
        mosaic (see the class docstring); draws from this dataset's generator."""
        first = self._buffered(index)
        if not self._buffer_full:  # filling: partners from the whole dataset
            return [first, *(self._buffered(int(i)) for i in self.rng.integers(0, len(self), 3))]
        pool = list(self._recent.values())
        return [first, *(pool[int(k)] for k in self.rng.integers(0, len(pool), 3))]

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
