"""NMS, mask assembly and the mapping of detections back to the source frame."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from slimseg.detections import Detections, FrameDetections, decode_rle, encode_rle
from slimseg.eval.postprocess import batch_to_frame_detections, to_frame_detections
from slimseg.ops.letterbox import boxes_to_frame, letterbox_mask, letterbox_params
from slimseg.ops.masks import assemble_masks, mask_windows, masks_to_frame, window_to_frame
from slimseg.ops.nms import non_max_suppression, yolov3_to_rows


def make_pred(rows: list[tuple], nc: int, nm: int = 0) -> torch.Tensor:
    """``[1, 4+nc+nm, A]`` from rows ``(cx, cy, w, h, cls, score[, coeffs])``."""
    pred = torch.zeros(1, 4 + nc + nm, len(rows))
    for a, (cx, cy, w, h, c, s, *coef) in enumerate(rows):
        pred[0, :4, a] = torch.tensor([cx, cy, w, h], dtype=torch.float32)
        pred[0, 4 + c, a] = s
        if nm:
            pred[0, 4 + nc :, a] = torch.tensor(coef[0], dtype=torch.float32)
    return pred


# ----------------------------------------------------------------------------- NMS


def test_nms_suppresses_overlaps_within_a_class() -> None:
    # Boxes 0/1 overlap with IoU 0.9 > 0.7; box 2 overlaps box 0 with IoU 1/3.
    pred = make_pred(
        [(50, 50, 20, 20, 0, 0.8), (51, 50, 20, 20, 0, 0.9), (60, 50, 20, 20, 0, 0.7)], nc=2
    )
    (d,) = non_max_suppression(pred, nc=2)
    assert len(d) == 2
    torch.testing.assert_close(d.scores, torch.tensor([0.9, 0.7]))
    torch.testing.assert_close(d.boxes[0], torch.tensor([41.0, 40.0, 61.0, 60.0]))
    assert d.classes.dtype == torch.int64 and d.classes.tolist() == [0, 0]
    assert d.coeffs.shape == (2, 0)


def test_nms_class_aware_vs_agnostic() -> None:
    pred = make_pred([(50, 50, 20, 20, 0, 0.9), (50, 50, 20, 20, 1, 0.8)], nc=2)
    (aware,) = non_max_suppression(pred, nc=2)
    (agn,) = non_max_suppression(pred, nc=2, agnostic=True)
    assert aware.classes.tolist() == [0, 1]
    assert agn.classes.tolist() == [0] and agn.scores.tolist() == pytest.approx([0.9])


def test_nms_single_best_class_per_anchor() -> None:
    pred = make_pred([(50, 50, 20, 20, 0, 0.3)], nc=3)
    pred[0, 4 + 2, 0] = 0.6  # the same anchor also scores class 2 higher
    (d,) = non_max_suppression(pred, nc=3)
    assert d.classes.tolist() == [2] and d.scores.tolist() == pytest.approx([0.6])


def test_nms_conf_threshold_is_strict() -> None:
    pred = make_pred([(10, 10, 5, 5, 0, 0.25), (40, 40, 5, 5, 0, 0.5), (80, 80, 5, 5, 1, 0.2)], 2)
    (d,) = non_max_suppression(pred, nc=2, conf=0.25)
    assert d.scores.tolist() == pytest.approx([0.5])


def test_nms_max_det_and_sorting_and_coeffs() -> None:
    rows = [
        (20.0 * i + 10, 10, 8, 8, i % 2, 0.1 + 0.02 * i, [float(i), -float(i)]) for i in range(20)
    ]
    pred = make_pred(rows, nc=2, nm=2)
    (d,) = non_max_suppression(pred, nc=2, max_det=5)
    assert len(d) == 5
    assert d.scores.tolist() == pytest.approx([0.1 + 0.02 * i for i in (19, 18, 17, 16, 15)])
    # The coefficients and boxes travel with their anchor.
    assert d.coeffs[:, 0].tolist() == [19.0, 18.0, 17.0, 16.0, 15.0]
    assert d.coeffs[:, 1].tolist() == [-19.0, -18.0, -17.0, -16.0, -15.0]
    assert d.boxes[:, 0].tolist() == [20.0 * i + 6 for i in (19, 18, 17, 16, 15)]
    assert d.classes.tolist() == [1, 0, 1, 0, 1]


def test_nms_max_candidates_keeps_the_best() -> None:
    rows = [(20.0 * i + 10, 10, 8, 8, 0, 0.1 + 0.02 * i) for i in range(10)]
    (d,) = non_max_suppression(make_pred(rows, nc=1), nc=1, max_candidates=3)
    assert d.scores.tolist() == pytest.approx([0.28, 0.26, 0.24])


def test_nms_batch_and_empty_image() -> None:
    a = make_pred([(50, 50, 20, 20, 0, 0.9)], nc=2, nm=3 * 0)
    b = make_pred([(50, 50, 20, 20, 0, 0.0001)], nc=2)
    out = non_max_suppression(torch.cat([a, b]), nc=2)
    assert [len(d) for d in out] == [1, 0]
    assert out[1].boxes.shape == (0, 4) and out[1].coeffs.shape == (0, 0)


def test_nms_rejects_bad_shapes() -> None:
    with pytest.raises(ValueError):
        non_max_suppression(torch.zeros(1, 5, 10), nc=2)


def test_yolov3_to_rows() -> None:
    pred = torch.zeros(1, 5 + 3, 2)
    pred[0, :4, 0] = torch.tensor([10.0, 20.0, 4.0, 6.0])
    pred[0, 4, 0] = 0.5
    pred[0, 5:, 0] = torch.tensor([0.2, 0.8, 0.4])
    rows = yolov3_to_rows(pred)
    assert rows.shape == (1, 4 + 3, 2)
    torch.testing.assert_close(rows[0, :, 0], torch.tensor([10.0, 20.0, 4.0, 6.0, 0.1, 0.4, 0.2]))
    (d,) = non_max_suppression(rows, nc=3, conf=0.05)
    assert d.classes.tolist() == [1] and d.scores.tolist() == pytest.approx([0.4])


# ----------------------------------------------------------------------------- masks


def box_mask(h: int, w: int, x1: int, y1: int, x2: int, y2: int) -> torch.Tensor:
    m = torch.zeros(h, w, dtype=torch.bool)
    m[y1:y2, x1:x2] = True
    return m


def test_assemble_mask_that_covers_the_box_is_box_shaped() -> None:
    # Proto 16x16 for a 64x64 input: logit +10 on proto cells rows 2..10, cols 3..12 (one cell
    # beyond the box on every side), -10 elsewhere. Box = cells rows 3..9, cols 4..11.
    proto = torch.full((1, 16, 16), -10.0)
    proto[0, 2:11, 3:13] = 10.0
    boxes = torch.tensor([[16.0, 12.0, 48.0, 40.0]])
    m = assemble_masks(torch.ones(1, 1), proto, boxes, (64, 64))
    assert m.dtype == torch.bool and m.shape == (1, 64, 64)
    assert torch.equal(m[0], box_mask(64, 64, 16, 12, 48, 40))


def test_assemble_mask_exactly_on_the_box_cells_loses_only_corners() -> None:
    # Positive exactly on the box's cells: each edge pixel interpolates 0.625 of an inside
    # cell (> 0.5, kept), each corner pixel 0.625² = 0.39 (dropped): bilinear rounds corners.
    proto = torch.full((1, 16, 16), -10.0)
    proto[0, 3:10, 4:12] = 10.0
    m = assemble_masks(torch.ones(1, 1), proto, torch.tensor([[16.0, 12.0, 48.0, 40.0]]), (64, 64))
    expected = box_mask(64, 64, 16, 12, 48, 40)
    for y, x in ((12, 16), (12, 47), (39, 16), (39, 47)):
        expected[y, x] = False
    assert torch.equal(m[0], expected)


def test_assemble_proto_crop_option_erodes_grid_aligned_corners() -> None:
    proto = torch.full((1, 16, 16), 10.0)  # certain everywhere
    box = torch.tensor([[16.0, 12.0, 48.0, 40.0]])
    full = box_mask(64, 64, 16, 12, 48, 40)
    assert torch.equal(assemble_masks(torch.ones(1, 1), proto, box, (64, 64))[0], full)
    cropped = assemble_masks(torch.ones(1, 1), proto, box, (64, 64), proto_crop=True)[0]
    assert int((full & ~cropped).sum()) == 4 and not (cropped & ~full).any()


def test_assemble_crop_removes_outside_pixels() -> None:
    proto = torch.full((2, 16, 16), 5.0)  # positive everywhere
    coeffs = torch.tensor([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])
    boxes = torch.tensor([[10.0, 20.0, 30.0, 50.0], [0.0, 0.0, 64.0, 64.0], [0.0, 0.0, 64.0, 64.0]])
    m = assemble_masks(coeffs, proto, boxes, (64, 64))
    assert torch.equal(m[0], box_mask(64, 64, 10, 20, 30, 50))
    assert m[1].all()
    assert not m[2].any()  # negative coefficient: no pixel


def test_assemble_fractional_box_uses_pixel_centres() -> None:
    proto = torch.full((1, 16, 16), 5.0)
    m = assemble_masks(torch.ones(1, 1), proto, torch.tensor([[10.4, 3.6, 20.5, 9.5]]), (64, 64))
    # columns whose centre x+0.5 is in [10.4, 20.5): 10..19; rows with y+0.5 in [3.6, 9.5): 4..8
    assert torch.equal(m[0], box_mask(64, 64, 10, 4, 20, 9))


def test_assemble_probabilities_chunking_and_empty() -> None:
    g = torch.Generator().manual_seed(1)
    proto = torch.randn(4, 8, 12, generator=g)
    coeffs = torch.randn(7, 4, generator=g)
    boxes = torch.tensor([[2.0, 3.0, 40.0, 30.0]]).repeat(7, 1)
    probs = assemble_masks(coeffs, proto, boxes, (32, 48), threshold=None)
    assert probs.dtype == torch.float32 and probs.shape == (7, 32, 48)
    assert probs.min() >= 0 and probs.max() <= 1
    torch.testing.assert_close(assemble_masks(coeffs, proto, boxes, (32, 48), None, chunk=2), probs)
    assert torch.equal(assemble_masks(coeffs, proto, boxes, (32, 48)), probs > 0.5)
    empty = assemble_masks(torch.zeros(0, 4), proto, torch.zeros(0, 4), (32, 48))
    assert empty.shape == (0, 32, 48) and empty.dtype == torch.bool


@pytest.mark.parametrize("proto_crop", [False, True])
def test_assemble_box_local_equals_full_frame_reference(proto_crop: bool) -> None:
    """The box-local gathers equal F.interpolate on the whole input followed by the crop."""
    g = torch.Generator().manual_seed(2)
    proto = torch.randn(8, 20, 24, generator=g) * 2
    n = 45  # more than one chunk, boxes of many sizes, some outside or degenerate
    xy = torch.rand(n, 2, generator=g) * torch.tensor([96.0, 80.0]) - 8
    wh = torch.rand(n, 2, generator=g) * 70
    boxes = torch.cat([xy, xy + wh], 1)
    boxes[0] = torch.tensor([0.0, 0.0, 96.0, 80.0])
    boxes[1] = torch.tensor([10.0, 10.0, 10.2, 30.0])  # no pixel centre inside
    coeffs = torch.randn(n, 8, generator=g)
    probs = assemble_masks(coeffs, proto, boxes, (80, 96), None, chunk=7, proto_crop=proto_crop)

    ref = (coeffs @ proto.view(8, -1)).sigmoid().view(n, 20, 24)
    if proto_crop:
        for i, (x1, y1, x2, y2) in enumerate((boxes / 4).tolist()):
            j, r = torch.arange(24.0), torch.arange(20.0)
            ref[i] *= ((r + 1 > y1) & (r < y2))[:, None] & ((j + 1 > x1) & (j < x2))[None]
    ref = F.interpolate(ref[:, None], size=(80, 96), mode="bilinear", align_corners=False)[:, 0]
    cy, cx = torch.arange(80.0) + 0.5, torch.arange(96.0) + 0.5
    b = boxes[:, :, None]
    inside = ((cy >= b[:, 1]) & (cy < b[:, 3]))[:, :, None] & ((cx >= b[:, 0]) & (cx < b[:, 2]))[
        :, None, :
    ]
    torch.testing.assert_close(probs, ref * inside, atol=1e-6, rtol=0)
    assert not probs[1].any() and probs[0].min() > 0
    masks = assemble_masks(coeffs, proto, boxes, (80, 96), chunk=5, proto_crop=proto_crop)
    assert torch.equal(masks, probs > 0.5)


@pytest.mark.parametrize("ratio", [1, 2, 4, 3])
def test_assemble_power_of_two_ratios_equal_full_frame_interpolation_bit_for_bit(
    ratio: int,
) -> None:
    """Power-of-two ratios crop + F.interpolate per window: the very pixels of upsampling the
    whole map; other ratios take the gather path (equal up to float rounding)."""
    g = torch.Generator().manual_seed(5)
    hp, wp = 12, 20
    h, w = ratio * hp, ratio * wp
    proto = torch.randn(6, hp, wp, generator=g) * 2
    n = 70
    xy = torch.rand(n, 2, generator=g) * torch.tensor([w + 8.0, h + 8.0]) - 8
    boxes = torch.cat([xy, xy + torch.rand(n, 2, generator=g) * torch.tensor([w, h])], 1)
    boxes[0] = torch.tensor([0.0, 0.0, w, h])
    boxes[1] = torch.tensor([w - 3.0, h - 2.0, w + 9.0, h + 9.0])  # at the bottom-right border
    coeffs = torch.randn(n, 6, generator=g)
    probs = assemble_masks(coeffs, proto, boxes, (h, w), None, chunk=16)
    full = (coeffs @ proto.view(6, -1)).sigmoid().view(n, 1, hp, wp)
    full = F.interpolate(full, size=(h, w), mode="bilinear", align_corners=False)[:, 0]
    cy, cx = torch.arange(h) + 0.5, torch.arange(w) + 0.5
    b = boxes[:, :, None]
    inside = ((cy >= b[:, 1]) & (cy < b[:, 3]))[:, :, None] & ((cx >= b[:, 0]) & (cx < b[:, 2]))[
        :, None, :
    ]
    if ratio == 3:
        torch.testing.assert_close(probs, full * inside, atol=2e-6, rtol=0)
    else:
        assert torch.equal(probs, full * inside)
        assert torch.equal(
            assemble_masks(coeffs, proto, boxes, (h, w), chunk=16), (full > 0.5) & inside
        )


def _detections_on_64px(seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``proto [4, 16, 16]``, 40 boxes ``[40, 4]`` on a 64 px input (one covering all of it,
    some partly outside), ``coeffs [40, 4]``."""
    g = torch.Generator().manual_seed(seed)
    proto = torch.randn(4, 16, 16, generator=g) * 3
    n = 40
    xy = torch.rand(n, 2, generator=g) * 70 - 6
    boxes = torch.cat([xy, xy + torch.rand(n, 2, generator=g) * 50], 1)
    boxes[0] = torch.tensor([0.0, 0.0, 64.0, 64.0])
    coeffs = torch.randn(n, 4, generator=g)
    return proto, boxes, coeffs


@pytest.mark.parametrize("frame_hw", [(45, 71), (150, 260), (20, 33), (64, 40), (64, 64)])
def test_window_to_frame_equals_the_dense_path(frame_hw: tuple[int, int]) -> None:
    proto, boxes, coeffs = _detections_on_64px(seed=6)
    p = letterbox_params(*frame_hw, 64)
    dense = masks_to_frame(assemble_masks(coeffs, proto, boxes, (64, 64), None), p, frame_hw)
    got = torch.zeros_like(dense)
    for k, probs, top, left in mask_windows(coeffs, proto, boxes, (64, 64), None, chunk=9):
        values, top_f, left_f = window_to_frame(probs, top, left, p, frame_hw, boxes[k])
        for d, i in enumerate(k.tolist()):  # windows lie inside the frame
            rows = top_f[d] + torch.arange(values.shape[1])
            cols = left_f[d] + torch.arange(values.shape[2])
            got[i, rows[:, None], cols[None, :]] = values[d]
    assert dense[0].any() and torch.equal(got, dense)


def test_masks_to_frame_inverts_the_letterbox_exactly() -> None:
    # Scale 2: frame 16x32 (h x w) → input 64x64, content 32x64 with 16 rows of padding on top.
    p = letterbox_params(16, 32, 64)
    assert (p.scale, p.new_w, p.new_h, p.left, p.top) == (2.0, 64, 32, 0, 16)
    frame = np.zeros((16, 32), np.uint8)
    frame[4:12, 8:24] = 1
    lb = torch.from_numpy(letterbox_mask(frame, p)).bool()
    assert lb[16 + 8 : 16 + 24, 16:48].all() and lb.sum() == 16 * 32
    back = masks_to_frame(lb[None], p, (16, 32))
    assert back.dtype == torch.bool and back.shape == (1, 16, 32)
    assert np.array_equal(back[0].numpy(), frame.astype(bool))
    # Padding on the left and right: frame 32x16 → left = 16.
    p2 = letterbox_params(32, 16, 64)
    assert (p2.left, p2.top) == (16, 0)
    back2 = masks_to_frame(
        torch.from_numpy(letterbox_mask(frame.T.copy(), p2))[None].bool(), p2, (32, 16)
    )
    assert np.array_equal(back2[0].numpy(), frame.T.astype(bool))


@pytest.mark.parametrize("frame_hw", [(45, 71), (150, 260), (20, 33), (64, 40)])
def test_masks_to_frame_box_local_equals_dense(frame_hw: tuple[int, int]) -> None:
    proto, boxes, coeffs = _detections_on_64px(seed=4)
    n = len(boxes)
    p = letterbox_params(*frame_hw, 64)
    probs = assemble_masks(coeffs, proto, boxes, (64, 64), None)
    dense = masks_to_frame(probs, p, frame_hw, chunk=9)
    local = masks_to_frame(probs, p, frame_hw, chunk=9, boxes=boxes)
    assert local.shape == (n, *frame_hw) and dense[0].any()
    assert torch.equal(local, dense)
    masks = probs > 0.5
    assert torch.equal(
        masks_to_frame(masks, p, frame_hw, boxes=boxes), masks_to_frame(masks, p, frame_hw)
    )


def test_masks_to_frame_drops_the_padding_and_checks_shapes() -> None:
    p = letterbox_params(16, 32, 64)
    m = torch.zeros(1, 64, 64, dtype=torch.bool)
    m[0, :16] = True  # only the top padding band
    assert not masks_to_frame(m, p, (16, 32)).any()
    with pytest.raises(ValueError):
        masks_to_frame(torch.zeros(1, 32, 32, dtype=torch.bool), p, (16, 32))


@pytest.mark.parametrize("proto_crop", [False, True])
def test_documented_steps_with_cv2_match(proto_crop: bool) -> None:
    """The C++ recipe of slimseg.ops.masks, written with numpy/cv2, gives the same masks."""
    g = torch.Generator().manual_seed(3)
    proto = torch.randn(3, 16, 16, generator=g) * 3
    coeffs = torch.randn(4, 3, generator=g)
    boxes = torch.tensor(
        [[5.3, 7.1, 50.2, 44.9], [0.0, 0.0, 64.0, 64.0], [20.0, 30.5, 33.3, 60.0], [1, 2, 9, 9]]
    )
    p = letterbox_params(45, 71, 64)  # scale 64/71: non-integer, 11 rows of padding on top
    probs = assemble_masks(coeffs, proto, boxes, (64, 64), None, proto_crop=proto_crop)
    ours = masks_to_frame(probs, p, (45, 71)).numpy()

    pr, cf, bx = proto.numpy(), coeffs.numpy(), boxes.numpy()
    for k in range(4):
        prob = 1 / (1 + np.exp(-np.tensordot(cf[k], pr, axes=1)))
        if proto_crop:
            x1, y1, x2, y2 = bx[k] * 16 / 64
            j = np.arange(16)
            prob = prob * (((j + 1 > y1) & (j < y2))[:, None] & ((j + 1 > x1) & (j < x2))[None])
        prob = cv2.resize(prob.astype(np.float32), (64, 64), interpolation=cv2.INTER_LINEAR)
        x1, y1, x2, y2 = bx[k]
        c = np.arange(64) + 0.5
        prob *= ((c >= y1) & (c < y2))[:, None] & ((c >= x1) & (c < x2))[None]
        content = prob[p.top : p.top + p.new_h, p.left : p.left + p.new_w]
        frame = cv2.resize(content, (71, 45), interpolation=cv2.INTER_LINEAR) > 0.5
        assert np.array_equal(frame, ours[k]), k


# ----------------------------------------------------------------------------- to frame


def test_to_frame_detections_boxes_masks_and_rle() -> None:
    h, w = 64, 128
    p = letterbox_params(h, w, 64)  # scale 0.5, content 64x32, 16 rows of padding on top
    meta = {"letterbox": p, "orig_shape": (h, w)}
    box_in = torch.tensor([[16.0, 24.0, 48.0, 40.0]])
    dets = Detections(box_in, torch.tensor([0.9]), torch.tensor([3]), torch.ones(1, 1))
    proto = torch.full((1, 16, 16), 6.0)

    fd = to_frame_detections(dets, proto, meta)
    np.testing.assert_allclose(fd.boxes, boxes_to_frame(box_in.numpy(), p, h, w))
    np.testing.assert_allclose(fd.boxes[0], [32.0, 16.0, 96.0, 48.0])
    assert fd.classes.tolist() == [3] and fd.image_hw == (h, w) and fd.rles is None
    assert fd.masks.shape == (1, h, w) and fd.masks.dtype == bool
    # Upsampling x2: edge pixels interpolate 0.75 inside / 0.25 outside, so the frame mask is
    # exactly the frame box.
    expected = np.zeros((h, w), bool)
    expected[16:48, 32:96] = True
    assert np.array_equal(fd.masks[0], expected)

    fr = to_frame_detections(dets, proto, meta, rle=True)
    assert fr.masks is None and isinstance(fr.rles[0]["counts"], str)
    assert fr.rles[0]["size"] == [h, w]
    assert np.array_equal(fr.dense_masks(), fd.masks)
    assert np.array_equal(decode_rle(encode_rle(fd.masks), (h, w)), fd.masks)

    det_only = to_frame_detections(dets, None, meta)
    assert not det_only.has_masks

    batch = batch_to_frame_detections([dets, dets], torch.stack([proto, proto]), [meta, meta])
    assert len(batch) == 2 and np.array_equal(batch[1].masks, fd.masks)


def test_to_frame_detections_empty() -> None:
    p = letterbox_params(30, 40, 32)
    empty = Detections(
        torch.zeros(0, 4), torch.zeros(0), torch.zeros(0, dtype=torch.long), torch.zeros(0, 2)
    )
    fd = to_frame_detections(empty, torch.zeros(2, 8, 8), {"letterbox": p, "orig_shape": (30, 40)})
    assert len(fd) == 0 and fd.masks.shape == (0, 30, 40)
    assert (
        to_frame_detections(
            empty, torch.zeros(2, 8, 8), {"letterbox": p, "orig_shape": (30, 40)}, rle=True
        ).rles
        == []
    )
    assert len(FrameDetections.empty((30, 40), with_masks=True).dense_masks()) == 0
