"""In-process checks of the multi-process fixes (tests/engine/test_ddp.py runs them on 2 ranks):
freezing before the strategy wraps the module, and a per-rank augmentation stream."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from slimseg.data.config import load_data_config
from slimseg.data.datamodule import SegDataModule
from slimseg.data.dataset import EpochIndex
from slimseg.data.synth import generate
from slimseg.engine.freeze import FreezeModules
from slimseg.engine.module import ZooModule
from slimseg.models.registry import get_spec


def test_freeze_happens_in_setup_before_the_strategy_wraps_the_module() -> None:
    """Lightning calls Callback.setup before strategy.setup (the DDP wrap, the optimizer);
    on_fit_start comes after both: too late for DDP's list of parameters to reduce."""
    module = ZooModule(get_spec("yolov8n-seg", 2).to_dict(), {"ema": False}, ["a", "b"])
    FreezeModules(["backbone", "neck"]).setup(None, module, "fit")
    frozen = [
        p.requires_grad for n in ("backbone", "neck") for p in getattr(module.model, n).parameters()
    ]
    assert frozen and not any(frozen)
    assert all(p.requires_grad for p in module.model.proto.parameters())
    trained = {id(p) for g in module.configure_optimizers().param_groups for p in g["params"]}
    assert not trained & {id(p) for p in module.model.backbone.parameters()}


@pytest.fixture(scope="module")
def tiny_yaml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return generate(
        tmp_path_factory.mktemp("rank") / "ds", 4, 1, 64, seed=3, progress=False
    ).data_yaml


def _first_sample(data_yaml: Path, rank: int | None) -> np.ndarray:
    dm = SegDataModule(load_data_config(data_yaml), imgsz=64, batch_size=2, workers=0, seed=0)
    if rank is not None:
        dm.trainer = SimpleNamespace(global_rank=rank, fit_loop=None)
    dm.setup("fit")
    return dm.train_set[EpochIndex(0, 0, True)].image


def test_each_rank_draws_its_own_augmentation_stream(tiny_yaml: Path) -> None:
    single = _first_sample(tiny_yaml, None)
    rank0, rank1 = _first_sample(tiny_yaml, 0), _first_sample(tiny_yaml, 1)
    assert np.array_equal(single, rank0)  # rank 0 is the one-process stream
    assert not np.array_equal(rank0, rank1)  # rank 1 augments the same image differently
    assert np.array_equal(rank1, _first_sample(tiny_yaml, 1))  # and reproducibly (resume)
