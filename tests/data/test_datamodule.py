"""From the embedded synthetic dataset to loss-ready batches, and the `data show` command."""

from __future__ import annotations

from pathlib import Path

import cv2
import pytest
import torch

from slimseg.cli.main import main
from slimseg.data.config import load_data_config
from slimseg.data.datamodule import SegDataModule
from slimseg.data.synth import generate


@pytest.fixture(scope="module")
def synth_yaml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "ds"
    return generate(out, train=12, val=4, imgsz=128, seed=5).data_yaml


@pytest.mark.parametrize("workers", [0, 2])
def test_datamodule_batches(synth_yaml: Path, workers: int) -> None:
    cfg = load_data_config(synth_yaml)
    dm = SegDataModule(cfg, imgsz=128, batch_size=4, workers=workers, seed=1)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    m = batch["targets"].shape[0]
    assert batch["images"].shape == (4, 3, 128, 128)
    assert m > 0 and batch["masks"].shape == (m, 32, 32)
    assert batch["targets"][:, 1].max() < len(cfg.names)
    boxes = batch["targets"][:, 2:]
    assert torch.all(boxes[:, 2:] > boxes[:, :2]) and boxes.max() <= 128
    val = next(iter(dm.val_dataloader()))
    assert val["images"].shape[0] == 4 and "letterbox" in val["meta"][0]


def test_train_loader_is_reproducible(synth_yaml: Path) -> None:
    def first_batch() -> dict:
        dm = SegDataModule(load_data_config(synth_yaml), imgsz=96, batch_size=3, workers=0, seed=4)
        dm.setup("fit")
        return next(iter(dm.train_dataloader()))

    a, b = first_batch(), first_batch()
    assert torch.equal(a["images"], b["images"]) and torch.equal(a["targets"], b["targets"])


def test_data_show_writes_a_grid(synth_yaml: Path, tmp_path: Path) -> None:
    out = tmp_path / "grid.png"
    argv = ["data", "show", "--data", str(synth_yaml), "--imgsz", "96", "--count", "6"]
    assert main([*argv, "--columns", "3", "--out", str(out)]) == 0
    img = cv2.imread(str(out))
    assert img.shape == (2 * 96 + 2, 3 * 96 + 4, 3)


@pytest.mark.parametrize("workers", [0, 2])
def test_persistent_workers_follow_the_epoch_and_the_mosaic_switch(
    synth_yaml: Path, workers: int
) -> None:
    def loader() -> torch.utils.data.DataLoader:
        dm = SegDataModule(load_data_config(synth_yaml), 96, 3, workers, seed=2, mosaic_epochs=1)
        dm.setup("fit")
        return dm.train_dataloader()

    dl = loader()
    assert dl.persistent_workers == (workers > 0)
    epoch0 = list(dl)
    assert all("mosaic" in m for b in epoch0 for m in b["meta"])
    dl.sampler.set_epoch(1)
    epoch1 = list(dl)  # the same worker processes when persistent; mosaic closed
    assert not any("mosaic" in m for b in epoch1 for m in b["meta"])
    # a fresh loader started at epoch 1 (a resumed run) sees the very same batches
    dl2 = loader()
    dl2.sampler.set_epoch(1)
    for a, b in zip(epoch1, list(dl2), strict=True):
        assert torch.equal(a["images"], b["images"]) and torch.equal(a["targets"], b["targets"])
    # and epoch 0 again gives epoch 0's batches (the augmentation is re-seeded per epoch)
    dl2.sampler.set_epoch(0)
    for a, b in zip(epoch0, list(dl2), strict=True):
        assert torch.equal(a["images"], b["images"]) and torch.equal(a["targets"], b["targets"])
