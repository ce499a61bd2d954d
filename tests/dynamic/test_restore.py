"""Background restoration: reference choice, PatchMatch fill of RGB and depth, bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from slimseg.dynamic.patchmatch import patchmatch
from slimseg.dynamic.restore import FrameData, restore_frame, select_references
from slimseg.sequence.restore_run import psnr, ssim_in

H, W = 120, 160


def _world(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A textured static background ``[H + 40, W + 80, 3]`` and its depth (a slanted plane)."""
    rng = np.random.default_rng(seed)
    blocks = rng.integers(0, 256, ((H + 40) // 4, (W + 80) // 4, 3), dtype=np.uint8)
    rgb = np.kron(blocks, np.ones((4, 4, 1), np.uint8))
    rgb = cv2.GaussianBlur(rgb, (3, 3), 0.7)
    depth = np.tile(np.linspace(2.0, 3.0, W + 80, dtype=np.float32), (H + 40, 1))
    return rgb, depth


def _view(cam_x: int, walker_x: int, seed: int = 0) -> tuple[np.ndarray, ...]:
    """Frame seen from camera offset ``cam_x`` with a 30×60 px walker at ``walker_x``:
    ``rgb``, ``depth``, walker mask, true background rgb and depth."""
    world, wdepth = _world(seed)
    bg = world[20 : 20 + H, 40 + cam_x : 40 + cam_x + W].copy()
    bg_d = wdepth[20 : 20 + H, 40 + cam_x : 40 + cam_x + W].copy()
    rgb, depth = bg.copy(), bg_d.copy()
    mask = np.zeros((H, W), bool)
    mask[30:90, walker_x : walker_x + 30] = True
    rgb[mask] = (200, 40, 40)
    depth[mask] = 1.2
    return rgb, depth, mask, bg, bg_d


def _frame(cam_x: int, walker_x: int) -> tuple[FrameData, np.ndarray, np.ndarray]:
    rgb, depth, mask, bg, bg_d = _view(cam_x, walker_x)
    return FrameData.build(rgb, depth, mask, 500), bg, bg_d


def test_region_seen_by_references_is_restored_better_than_telea() -> None:
    target, truth, truth_d = _frame(0, 65)
    cands = {
        1: _frame(6, 25)[0],  # walker has moved left, camera right
        2: _frame(-5, 110)[0],  # walker has moved right, camera left
        3: _frame(2, 63)[0],  # walker still in place: covers nothing new
    }
    refs = select_references(target, cands, min_matches=20)
    assert refs[0].index in (1, 2) and refs[0].gain > 0.5
    assert 2 <= len(refs) <= 4 and all(r.parallax_px >= 1.0 for r in refs)
    assert all(r.gain == 0.0 for r in refs if r.index == 3)  # frame 3 uncovers nothing
    out = restore_frame(target, [(cands[r.index], r) for r in refs])
    hole = target.removed
    assert out.coverage == pytest.approx(1.0)
    ours = psnr(out.rgb, truth, hole)
    telea = cv2.inpaint(target.rgb, hole.astype(np.uint8), 3, cv2.INPAINT_TELEA)
    assert ours > 30.0
    assert ours > psnr(telea, truth, hole) + 10.0
    assert ssim_in(out.rgb, truth, hole) > 0.9
    assert np.array_equal(out.rgb[~hole], target.rgb[~hole])  # known pixels untouched
    # depth comes through the same field: the plane, not the walker's 1.2 m
    assert np.median(np.abs(out.depth[hole] - truth_d[hole])) < 0.02
    assert out.depth[hole].min() > 1.5


def test_references_need_matches_and_prefer_parallax() -> None:
    target, _, _ = _frame(0, 65)
    blank = FrameData.build(
        np.full((H, W, 3), 128, np.uint8), np.ones((H, W), np.float32), np.zeros((H, W), bool)
    )
    same_view = _frame(0, 25)[0]  # no parallax, but uncovers the walker region
    moved = _frame(6, 25)[0]
    refs = select_references(target, {0: blank, 1: same_view, 2: moved}, min_matches=20)
    assert [r.index for r in refs][:1] == [2]  # parallax first; the blank frame never
    assert 0 not in [r.index for r in refs]
    assert select_references(target, {0: blank}) == []


def test_patchmatch_copies_only_valid_source_pixels() -> None:
    rng = np.random.default_rng(1)
    big = cv2.resize(
        rng.random((30, 40, 3)).astype(np.float32), (200, 160), interpolation=cv2.INTER_CUBIC
    )
    truth = big[10:130, 10:170]
    source = big[13:133, 8:168]  # the same scene, shifted by (3, -2)
    hole = np.zeros((H, W), bool)
    hole[40:80, 60:100] = True
    source[90:, 60:100] = 1.0  # garbage the source may not give (its own removed region)
    valid = np.ones((1, H, W), bool)
    valid[0, 90:, 60:100] = False
    target = truth.copy()
    target[hole] = 0.0
    field = patchmatch(target, hole, source[None], valid, patch=7)
    assert (field.ref[hole] == 0).all()
    assert valid[0, field.qy[hole], field.qx[hole]].all()
    assert np.array_equal(field.image[~hole], truth[~hole])
    err = float(((field.image - truth)[hole] ** 2).mean())
    assert 10 * np.log10(1.0 / max(err, 1e-12)) > 30.0


def test_bad_input_is_reported() -> None:
    img = np.zeros((H, W, 3), np.float32)
    hole = np.zeros((H, W), bool)
    hole[5:9, 5:9] = True
    with pytest.raises(ValueError, match="do not agree"):
        patchmatch(img, hole[:-1], img[None], np.ones((1, H, W), bool))
    with pytest.raises(ValueError, match="odd"):
        patchmatch(img, hole, img[None], np.ones((1, H, W), bool), patch=4)
    with pytest.raises(ValueError, match="no valid source"):
        patchmatch(img, hole, img[None], np.zeros((1, H, W), bool))
    with pytest.raises(ValueError, match="same height and width"):
        FrameData.build(np.zeros((H, W, 3), np.uint8), np.zeros((H, W)), hole[:-1])
    with pytest.raises(ValueError, match="uint8"):
        FrameData.build(img, np.zeros((H, W)), hole)


def test_nothing_to_copy_from_leaves_the_frame_unchanged() -> None:
    rgb = np.full((H, W, 3), 7, np.uint8)
    target = FrameData.build(rgb, np.ones((H, W), np.float32), np.ones((H, W), bool))
    out = restore_frame(target, [])
    assert out.coverage == 0.0 and out.field is None and np.array_equal(out.rgb, rgb)
