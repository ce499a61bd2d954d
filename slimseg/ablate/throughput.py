"""Training throughput that survives a resume: images and seconds per finished epoch."""

from __future__ import annotations

import json
import time
from pathlib import Path

import lightning as L

from slimseg.utils.atomic import write_json


class ThroughputMeter(L.Callback):
    """Times each training epoch from its start to its last batch (data loading and the
    optimiser step included, validation excluded) and counts its images.

    Per-epoch entries go to ``path`` (JSON ``{"epochs": {"3": [images, seconds]}}``) at each
    epoch end, so an interrupted run re-measures only the epoch it lost.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.epochs: dict[str, list[float]] = read_epochs(self.path)
        self._start = 0.0
        self._last = 0.0
        self._images = 0

    def on_train_epoch_start(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        self._start = self._last = time.perf_counter()
        self._images = 0

    def on_train_batch_end(
        self, trainer: L.Trainer, module: L.LightningModule, outputs: object, batch: dict, i: int
    ) -> None:
        self._images += int(batch["images"].shape[0])
        self._last = time.perf_counter()

    def on_train_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if not trainer.is_global_zero or self._images == 0:
            return
        seconds = self._last - self._start
        images = self._images * trainer.world_size  # every rank sees its own share
        self.epochs[str(trainer.current_epoch)] = [images, round(seconds, 4)]
        write_json(self.path, {"epochs": self.epochs}, indent=1)


def read_epochs(path: Path) -> dict[str, list[float]]:
    """Per-epoch ``[images, seconds]`` recorded so far (empty when none)."""
    if not Path(path).is_file():
        return {}
    return dict(json.loads(Path(path).read_text())["epochs"])


def images_per_second(path: Path) -> float:
    """Training images per second over every recorded epoch (NaN when none)."""
    epochs = read_epochs(path).values()
    seconds = sum(s for _, s in epochs)
    return sum(n for n, _ in epochs) / seconds if seconds > 0 else float("nan")
