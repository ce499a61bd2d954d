"""The YOLOv8 loss learns on generated data and keeps DDP-safe graphs."""

from __future__ import annotations

import pytest
import torch

from slimseg.data.collate import network_input
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
    batch = next(iter(dm.train_dataloader()))
    batch["images"] = network_input(batch["images"])
    return batch, len(cfg.names)


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
    # the 0.6x drop comes by step 10; step 18: 0.38x / 0.47x (n-seg / gs-rep), 25: 0.36x / 0.40x
    for _ in range(18):
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


def test_loss_values_on_a_hand_checked_case() -> None:
    """One anchor, one box, one class, one prototype: every term computed by hand.

    Level: stride 8, a 1×1 map (input 8×8), anchor centre (4, 4) px; GT box (0, 0, 8, 8) px =
    (0, 0, 1, 1) in stride units, side distances 0.5. All box/class logits 0: the DFL
    distribution over reg_max = 4 bins is uniform, expected distance 1.5, predicted box
    (-1, -1, 2, 2): concentric squares, IoU = CIoU = 1/9. Class score σ(0) = 0.5; the only
    candidate is assigned with soft target IoU·align / (align + 1e-9), align = σ^0.5·IoU^6
    (the assigner's eps matters here: align is only 1.3e-6).
    """
    import math

    from slimseg.models.yolo import RawOutputs

    reg_max, nc = 4, 1
    feats = [torch.zeros(1, 4 * reg_max + nc, 1, 1)]
    coeffs = torch.ones(1, 1, 1)  # [B, nm, A]
    proto = torch.tensor([[[[2.0, -2.0], [0.0, 0.0]]]])  # [B, nm, 2, 2] (stride 4)
    gt_mask = torch.tensor([[[1.0, 0.0], [0.0, 1.0]]])  # [M, 2, 2]
    targets = torch.tensor([[0.0, 0.0, 0.0, 0.0, 8.0, 8.0]])
    loss_fn = YOLOv8Loss(nc, strides=(8,), reg_max=reg_max)
    total, terms = loss_fn(RawOutputs(feats, coeffs, proto), targets, gt_mask)

    align = math.sqrt(0.5) * (1 / 9) ** 6
    target_score = (1 / 9) * align / (align + 1e-9)
    cls = math.log(2)  # BCE(0, t) = log 2 for any t; / max(Σ targets, 1) = 1
    box = (1 - 1 / 9) * target_score  # (1 − CIoU) · weight / 1
    dfl = math.log(4) * target_score  # CE of a uniform 4-bin distribution, either bin
    sp = lambda x: math.log1p(math.exp(x))  # noqa: E731  softplus
    seg = (sp(-2) + sp(-2) + sp(0) + sp(0)) / 4  # BCE over the 2×2 crop / box area 4 / 1 fg
    expected = {"box": box, "cls": cls, "dfl": dfl, "seg": seg}
    for k, v in expected.items():
        assert terms[k].item() == pytest.approx(v, rel=1e-5), k
    assert total.item() == pytest.approx(7.5 * box + 0.5 * cls + 1.5 * dfl + 7.5 * seg, rel=1e-5)


def test_loss_without_targets_is_the_background_bce() -> None:
    """No boxes: only the class term, Σ softplus(logit) over every anchor and class."""
    from slimseg.models.yolo import RawOutputs

    torch.manual_seed(0)
    reg_max, nc = 4, 3
    feats = [torch.randn(2, 4 * reg_max + nc, 2, 2), torch.randn(2, 4 * reg_max + nc, 1, 1)]
    loss_fn = YOLOv8Loss(nc, strides=(8, 16), reg_max=reg_max)
    total, terms = loss_fn(RawOutputs(feats, None, None), torch.zeros(0, 6))
    logits = torch.cat([f[:, 4 * reg_max :].reshape(2, nc, -1) for f in feats], 2)
    cls = torch.nn.functional.softplus(logits).sum().item()
    assert terms["cls"].item() == pytest.approx(cls, rel=1e-6)
    assert terms["box"].item() == terms["dfl"].item() == 0.0
    assert total.item() == pytest.approx(0.5 * cls * 2, rel=1e-6)  # × batch size 2
