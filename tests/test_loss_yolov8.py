"""The YOLOv8 loss learns on generated data and keeps DDP-safe graphs."""

from __future__ import annotations

import pytest
import torch

from slimseg.data.config import load_data_config
from slimseg.data.datamodule import SegDataModule
from slimseg.data.synth import generate
from slimseg.losses.yolov8_seg import YOLOv8Loss, pad_targets
from slimseg.models.registry import build_model


@pytest.fixture(scope="module")
def batch(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, int]:
    out = tmp_path_factory.mktemp("synth") / "ds"
    cfg = load_data_config(generate(out, 8, 2, 160, seed=11, progress=False).data_yaml)
    dm = SegDataModule(cfg, imgsz=160, batch_size=8, workers=0, seed=0)
    dm.setup("fit")
    return next(iter(dm.train_dataloader())), len(cfg.names)


def test_pad_targets() -> None:
    t = torch.tensor([[1, 3, 0, 0, 5, 5], [0, 1, 1, 1, 2, 2], [1, 0, 2, 2, 9, 9.0]])
    labels, boxes, valid, rows = pad_targets(t, 3)
    assert labels.tolist() == [[1, 0], [3, 0], [0, 0]]
    assert valid.tolist() == [[True, False], [True, True], [False, False]]
    assert rows.tolist() == [[1, -1], [0, 2], [-1, -1]]
    assert boxes[1, 1].tolist() == [2, 2, 9, 9]


@pytest.mark.parametrize("name", ["yolov8n-seg", "yolov8n-seg-gs-rep"])
def test_loss_decreases_on_generated_data(batch: tuple[dict, int], name: str) -> None:
    data, nc = batch
    torch.manual_seed(0)
    model = build_model(name, num_classes=nc).train()
    loss_fn = YOLOv8Loss(nc)
    opt = torch.optim.AdamW(model.parameters(), lr=2e-3)
    history = []
    for _ in range(25):
        loss, terms = loss_fn(model(data["images"]), data["targets"], data["masks"])
        assert set(terms) == {"box", "cls", "dfl", "seg"}
        assert torch.isfinite(loss)
        opt.zero_grad()
        loss.backward()
        opt.step()
        history.append(loss.item())
    assert history[-1] < 0.6 * history[0]


def test_no_targets_keeps_every_parameter_in_graph(batch: tuple[dict, int]) -> None:
    data, nc = batch
    model = build_model("yolov8n-seg", num_classes=nc).train()
    loss, terms = YOLOv8Loss(nc)(model(data["images"]), torch.zeros(0, 6), torch.zeros(0, 40, 40))
    loss.backward()
    assert terms["box"] == 0 and terms["seg"] == 0 and terms["cls"] > 0
    assert all(p.grad is not None for p in model.parameters() if p.requires_grad)


def test_detect_only_model(batch: tuple[dict, int]) -> None:
    data, nc = batch
    model = build_model("yolov8n", num_classes=nc).train()
    loss, terms = YOLOv8Loss(nc)(model(data["images"]), data["targets"])
    assert set(terms) == {"box", "cls", "dfl"} and torch.isfinite(loss)
