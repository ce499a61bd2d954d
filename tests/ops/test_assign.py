"""Task-aligned assignment on hand-built cases."""

from __future__ import annotations

import torch

from slimseg.ops.assign import task_aligned_assign


def _grid(n: int, stride: float) -> torch.Tensor:
    ys, xs = torch.meshgrid(torch.arange(n) + 0.5, torch.arange(n) + 0.5, indexing="ij")
    return torch.stack((xs, ys), -1).reshape(-1, 2) * stride


def test_candidates_inside_box_and_topk() -> None:
    pts = _grid(8, 8.0)  # 64 anchors, centres at 4, 12, ..., 60
    a = len(pts)
    gt = torch.tensor([[[0.0, 0.0, 24.0, 24.0]]])  # covers the 3x3 top-left centres
    pred_boxes = gt.expand(1, a, 4).clone()  # every prediction equals the GT
    scores = torch.full((1, a, 2), 0.5)
    out = task_aligned_assign(
        scores, pred_boxes, pts, torch.tensor([[1]]), gt, torch.tensor([[True]]), topk=4
    )
    fg = out.fg[0].view(8, 8)
    assert fg.sum() == 4 and fg[:3, :3].sum() == 4  # only centres inside, top-4
    assert torch.equal(out.boxes[0][out.fg[0]], gt[0].expand(4, 4))
    # perfect IoU and equal scores → normalised target = max IoU = 1 on class 1 only
    assert torch.allclose(out.scores[0][out.fg[0]], torch.tensor([0.0, 1.0]).expand(4, 2))
    assert out.scores[0][~out.fg[0]].abs().sum() == 0


def test_contested_anchor_goes_to_higher_iou() -> None:
    pts = torch.tensor([[10.0, 10.0]])
    gts = torch.tensor([[[0.0, 0.0, 20.0, 20.0], [5.0, 5.0, 40.0, 40.0]]])
    pred = torch.tensor([[[0.0, 0.0, 21.0, 21.0]]])  # overlaps the first GT most
    out = task_aligned_assign(
        torch.full((1, 1, 3), 0.9),
        pred,
        pts,
        torch.tensor([[0, 2]]),
        gts,
        torch.tensor([[True, True]]),
    )
    assert out.fg.item() and out.gt_index.item() == 0
    assert out.scores[0, 0].argmax().item() == 0


def test_padding_slots_are_ignored_and_empty_batch() -> None:
    pts = _grid(4, 8.0)
    gt = torch.tensor([[[0.0, 0.0, 32.0, 32.0]]])
    out = task_aligned_assign(
        torch.full((1, 16, 1), 0.5),
        gt.expand(1, 16, 4),
        pts,
        torch.tensor([[0]]),
        gt,
        torch.tensor([[False]]),
    )
    assert not out.fg.any()
    empty = task_aligned_assign(
        torch.rand(2, 16, 1),
        torch.rand(2, 16, 4),
        pts,
        torch.zeros(2, 0, dtype=torch.long),
        torch.zeros(2, 0, 4),
        torch.zeros(2, 0, dtype=torch.bool),
    )
    assert not empty.fg.any() and empty.scores.shape == (2, 16, 1)
