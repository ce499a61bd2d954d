"""Darknet-style YOLOv3 loss: assignment, term bookkeeping, ignore mask, gradients, overfit."""

from __future__ import annotations

import copy
import math

import pytest
import torch

from slimseg.losses.yolov3 import YOLOv3Loss, assign_targets, wh_iou
from slimseg.models.darknet_yolov3 import STANDARD_ANCHORS, STRIDES, Darknet19YOLOv3
from slimseg.models.registry import build_model

SIZE = 64  # input side; grids 8×8, 4×4, 2×2
NC = 2
ANCHORS = torch.tensor(STANDARD_ANCHORS, dtype=torch.float32)  # [3, 3, 2]
GRIDS = [(SIZE // s, SIZE // s) for s in STRIDES]


def box(cx: float, cy: float, w: float, h: float, b: int = 0, c: int = 0) -> list[float]:
    """One target row ``(batch, class, x1, y1, x2, y2)`` from a centre and size."""
    return [b, c, cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2]


@pytest.fixture(scope="module")
def model() -> Darknet19YOLOv3:
    torch.manual_seed(0)
    return build_model("darknet19-yolov3", num_classes=NC).train()


def zero_outputs(batch: int = 2, fill_obj: float = 0.0) -> list[torch.Tensor]:
    """Raw outputs ``3 × [B, 3, 5+NC, h, w]`` of zeros, objectness logits set to ``fill_obj``."""
    outs = []
    for h, w in GRIDS:
        p = torch.zeros(batch, 3, 5 + NC, h, w)
        p[:, :, 4] = fill_obj
        outs.append(p)
    return outs


# ---------------------------------------------------------------- assignment


def test_assignment_hand_built() -> None:
    targets = torch.tensor(
        [
            box(20, 28, 10, 13, b=0),  # anchor 0 exactly → level 0, anchor 0, cell (2, 3)
            box(33, 40, 62, 45, b=1),  # anchor 4 exactly → level 1, anchor 1, cell (2, 2)
            box(64, 64, 120, 90, b=1),  # ≈ 116×90 → level 2, anchor 0; centre on border → (1, 1)
            box(-2, 5, 30, 25, b=0),  # ≈ 33×23 → level 0, anchor 2; centre outside → (0, 0)
            [0, 1, 10, 10, 10, 20],  # zero width: dropped
        ]
    )
    a = assign_targets(targets, ANCHORS, STRIDES, GRIDS)
    assert a.target.tolist() == [0, 1, 2, 3]
    assert a.batch.tolist() == [0, 1, 1, 0]
    assert a.level.tolist() == [0, 1, 2, 0]
    assert a.anchor.tolist() == [0, 1, 0, 2]
    assert a.gi.tolist() == [2, 2, 1, 0]
    assert a.gj.tolist() == [3, 2, 1, 0]


def test_assignment_matches_reference_loop() -> None:
    g = torch.Generator().manual_seed(1)
    n = 200
    size = 416
    grids = [(size // s, size // s) for s in STRIDES]
    cxy = torch.rand(n, 2, generator=g) * size
    wh = torch.exp(torch.rand(n, 2, generator=g) * math.log(400.0)) + 1.0
    rows = torch.cat(
        (torch.arange(n)[:, None].float(), torch.zeros(n, 1), cxy - wh / 2, cxy + wh / 2), 1
    )  # one box per image: no slot collisions
    a = assign_targets(rows, ANCHORS, STRIDES, grids)
    assert a.target.tolist() == list(range(n))
    flat = ANCHORS.reshape(-1, 2).tolist()
    for k in range(n):
        w, h = wh[k].tolist()
        ious = [
            min(w, aw) * min(h, ah) / (w * h + aw * ah - min(w, aw) * min(h, ah)) for aw, ah in flat
        ]
        best = max(range(9), key=lambda i: ious[i])
        lvl, s = best // 3, STRIDES[best // 3]
        assert (a.level[k].item(), a.anchor[k].item()) == (lvl, best % 3)
        assert a.gi[k].item() == min(int(cxy[k, 0].item() // s), grids[lvl][1] - 1)
        assert a.gj[k].item() == min(int(cxy[k, 1].item() // s), grids[lvl][0] - 1)


def test_assignment_duplicate_slot_keeps_last() -> None:
    targets = torch.tensor(
        [
            box(20, 28, 10, 13, b=0, c=0),
            box(21, 27, 11, 12, b=0, c=1),  # same slot as row 0: wins
            box(21, 27, 11, 12, b=1, c=1),  # same slot, other image: kept
        ]
    )
    a = assign_targets(targets, ANCHORS, STRIDES, GRIDS)
    assert sorted(a.target.tolist()) == [1, 2]


def test_assignment_empty() -> None:
    a = assign_targets(torch.zeros(0, 6), ANCHORS, STRIDES, GRIDS)
    assert a.target.numel() == 0 and a.level.numel() == 0


def test_wh_iou() -> None:
    iou = wh_iou(torch.tensor([[10.0, 13.0]]), torch.tensor([[10.0, 13.0], [20.0, 13.0]]))
    assert torch.allclose(iou, torch.tensor([[1.0, 0.5]]))


# ---------------------------------------------------------------- loss values


def test_loss_finite_positive(model: Darknet19YOLOv3) -> None:
    x = torch.rand(2, 3, SIZE, SIZE)
    targets = torch.tensor([box(20, 28, 10, 13, b=0, c=1), box(33, 40, 62, 45, b=1)])
    with torch.no_grad():
        total, terms = YOLOv3Loss(model)(model(x), targets, (SIZE, SIZE))
    assert total.ndim == 0 and torch.isfinite(total) and total > 0
    assert set(terms) == {"box", "obj", "noobj", "cls"}
    assert all(v > 0 and not v.requires_grad for v in terms.values())
    assert torch.allclose(total, sum(terms.values()))


def test_no_targets_only_noobj() -> None:
    loss = YOLOv3Loss(anchors=STANDARD_ANCHORS, strides=STRIDES, num_classes=NC)
    outs = [p.requires_grad_() for p in zero_outputs()]
    total, terms = loss(outs, torch.zeros(0, 6), SIZE)
    assert terms["box"] == 0 and terms["cls"] == 0 and terms["obj"] == 0
    # every prediction costs λ_noobj · softplus(0) = 0.5 · log 2; per image: × predictions/image
    n_pred = 3 * sum(h * w for h, w in GRIDS)
    assert torch.isclose(terms["noobj"], torch.tensor(0.5 * math.log(2.0) * n_pred))
    total.backward()
    assert all(p.grad is not None and p.grad[:, :, 4].abs().sum() > 0 for p in outs)


def test_perfect_prediction_near_zero() -> None:
    targets = torch.tensor(
        [
            box(21, 27, 11, 12, b=0, c=1),
            box(35, 41, 60, 47, b=1, c=0),
            box(40, 30, 110, 95, b=1, c=1),
        ]
    )
    a = assign_targets(targets, ANCHORS, STRIDES, GRIDS)
    assert a.target.numel() == 3
    outs = zero_outputs(fill_obj=-30.0)
    for k in range(3):
        lvl, an, gj, gi, b = (int(v[k]) for v in (a.level, a.anchor, a.gj, a.gi, a.batch))
        t = targets[int(a.target[k])]
        s = STRIDES[lvl]
        cx, cy = (t[2] + t[4]) / 2, (t[3] + t[5]) / 2
        w, h = t[4] - t[2], t[5] - t[3]
        fx, fy = cx / s - gi, cy / s - gj
        p = outs[lvl][b, an, :, gj, gi]
        p[0], p[1] = torch.logit(fx), torch.logit(fy)
        p[2], p[3] = torch.log(w / ANCHORS[lvl, an, 0]), torch.log(h / ANCHORS[lvl, an, 1])
        p[4] = 30.0
        p[5:] = -30.0
        p[5 + int(t[1])] = 30.0
    total, terms = YOLOv3Loss(anchors=ANCHORS, strides=STRIDES, num_classes=NC)(
        outs, targets, (SIZE, SIZE)
    )
    assert terms["box"].abs() < 1e-4
    assert terms["cls"] < 1e-4
    assert terms["obj"] < 1e-4
    assert terms["noobj"] < 1e-4
    assert total.abs() < 1e-3
    # a small error in one box is penalised
    outs[0][0, :, 0] += 0.5
    _, worse = YOLOv3Loss(anchors=ANCHORS, strides=STRIDES, num_classes=NC)(
        outs, targets, (SIZE, SIZE)
    )
    assert worse["box"] > 1e-3


def test_ignore_mask_spares_good_unassigned_prediction() -> None:
    targets = torch.tensor([box(20, 28, 10, 13, b=0)])  # assigned: level 0, anchor 0, (3, 2)
    outs = zero_outputs()
    # anchor 1 (16×30) at the same cell decodes to exactly the GT box, with a confident obj
    p = outs[0][0, 1, :, 3, 2]
    p[2], p[3] = math.log(10 / 16), math.log(13 / 30)
    p[4] = 5.0
    kw = {"anchors": ANCHORS, "strides": STRIDES, "num_classes": NC}
    _, with_ignore = YOLOv3Loss(**kw)(outs, targets, SIZE)
    _, no_ignore = YOLOv3Loss(ignore_iou=1.5, **kw)(outs, targets, SIZE)
    expected = 0.5 * torch.nn.functional.softplus(torch.tensor(5.0)) / 2  # λ_noobj · BCE / B
    assert torch.isclose(no_ignore["noobj"] - with_ignore["noobj"], expected, atol=1e-5)
    assert torch.equal(with_ignore["box"], no_ignore["box"])


def test_loss_is_mean_per_image() -> None:
    g = torch.Generator().manual_seed(3)
    outs = [torch.randn(p.shape, generator=g) for p in zero_outputs()]
    targets = torch.tensor([box(20, 28, 10, 13, b=0), box(33, 40, 62, 45, b=1, c=1)])
    loss = YOLOv3Loss(anchors=ANCHORS, strides=STRIDES, num_classes=NC)
    total, _ = loss(outs, targets, SIZE)
    doubled = [torch.cat((p, p)) for p in outs]
    shifted = targets.clone()
    shifted[:, 0] += 2
    total2, _ = loss(doubled, torch.cat((targets, shifted)), SIZE)
    assert torch.isclose(total, total2, rtol=1e-5)


def test_box_weight_two_minus_wh() -> None:
    loss = YOLOv3Loss(anchors=ANCHORS, strides=STRIDES, num_classes=NC, lambda_coord=1.0)
    outs = zero_outputs()
    targets = torch.tensor([box(20, 28, 10, 13)])  # tx*, ty* = 0.5 and tw*, th* = 0: exact
    outs[0][0, 0, 2, 3, 2] = 1.0  # tw off by one at the assigned slot
    _, terms = loss(outs, targets, SIZE)
    weight = 2 - (10 / SIZE) * (13 / SIZE)
    assert torch.isclose(terms["box"], torch.tensor(weight * 0.5 * 1.0**2 / 2))  # ½ err² / B


def test_invalid_targets_raise() -> None:
    loss = YOLOv3Loss(anchors=ANCHORS, strides=STRIDES, num_classes=NC)
    with pytest.raises(ValueError, match="classes"):
        loss(zero_outputs(), torch.tensor([box(20, 28, 10, 13, c=NC)]), SIZE)
    with pytest.raises(ValueError, match="batch"):
        loss(zero_outputs(), torch.tensor([box(20, 28, 10, 13, b=2)]), SIZE)
    with pytest.raises(ValueError):
        YOLOv3Loss()


# ---------------------------------------------------------------- training signal


def test_gradients_reach_prediction_convs(model: Darknet19YOLOv3) -> None:
    model.zero_grad(set_to_none=True)
    x = torch.rand(2, 3, SIZE, SIZE)
    targets = torch.tensor(
        [box(20, 28, 10, 13, b=0), box(33, 40, 62, 45, b=1, c=1), box(32, 32, 120, 90, b=1)]
    )
    total, _ = YOLOv3Loss(model)(model(x), targets, SIZE)
    total.backward()
    for head in (model.head_p3, model.head_p4, model.head_p5):
        for param in (head.pred.weight, head.pred.bias):
            assert param.grad is not None
            assert torch.isfinite(param.grad).all() and param.grad.abs().sum() > 0
        # box logits (tx..th) of anchor 0 receive gradient on every level
        assert head.pred.bias.grad.view(3, 5 + NC)[:, :4].abs().sum() > 0
    model.zero_grad(set_to_none=True)


def test_short_optimisation_decreases_loss(model: Darknet19YOLOv3) -> None:
    torch.manual_seed(0)
    net = copy.deepcopy(model).train()
    x = torch.rand(2, 3, SIZE, SIZE)
    targets = torch.tensor(
        [box(19, 25, 22, 30, b=0, c=0), box(47, 46, 26, 32, b=0, c=1), box(32, 32, 32, 32, b=1)]
    )
    loss = YOLOv3Loss(net)
    opt = torch.optim.SGD(net.parameters(), lr=3e-4, momentum=0.9)
    first = last = None
    for _ in range(20):  # 30 steps cost half as much again; the 4× drop comes by step 13
        total, _ = loss(net(x), targets, SIZE)
        opt.zero_grad()
        total.backward()
        opt.step()
        first = total.item() if first is None else first
        last = total.item()
    assert math.isfinite(last)
    # ≈ 29 → ≈ 3.2 (9×) in 20 steps with seed 0, 7× with seed 1; pin a 4× drop
    assert last < first / 4.0, (first, last)
