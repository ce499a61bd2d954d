"""The stillness test: a person whose depth stays the same for still_frames gives points back."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import block_texture, frame_objects, sideways_pose

from slimseg.dynamic.chain_config import ChainConfig
from slimseg.dynamic.epipolar import PnpPose, PreviousFrame, orb_features
from slimseg.dynamic.frame_masker import FrameMasker
from slimseg.dynamic.masking_settings import DEFAULT, PAPERS
from slimseg.dynamic.modes import Mode
from slimseg.dynamic.stillness import (
    STILL_FRACTION,
    STILL_KEEP_FRACTION,
    changed_fractions,
    compared_frames,
    depth_span,
    grid_iou,
    still_objects,
)
from slimseg.objects import Objects

HW = (120, 160)
CAMERA = (100.0, 100.0, 79.5, 59.5)
WALL, STATUE, WALKER = 5.0, 2.5, 3.0
# world x ranges (m) at the object's depth: the statue, and the walker at frame 0
STATUE_X, WALKER_X0, WALKER_SPEED = (-1.0, -0.45), (0.3, 0.9), 0.05  # m per frame


def _render(walker_dx: float, cam_x: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """``(depth float32 [H, W], instance masks bool [2, H, W])``: a wall, the statue and the
    walker moved by ``walker_dx`` m (fronto-parallel, rows 20-100), seen from ``cam_x``."""
    fx, _, cx, _ = CAMERA
    u = np.arange(HW[1], dtype=np.float64)
    depth = np.full(HW, WALL, np.float32)
    masks = np.zeros((2, *HW), bool)
    walker = (WALKER_X0[0] + walker_dx, WALKER_X0[1] + walker_dx)
    for k, (z, (x0, x1)) in sorted(enumerate([(STATUE, STATUE_X), (WALKER, walker)]),
                                   key=lambda e: -e[1][0]):  # fmt: skip
        x = (u - cx) * z / fx + cam_x
        cols = (x >= x0) & (x < x1)
        depth[20:100, cols] = z
        masks[:, 20:100, cols] = False
        masks[k, 20:100, cols] = True
    return depth, masks


def _pose(tx: float) -> PnpPose:
    return sideways_pose(CAMERA, tx)


def _earlier(depth: np.ndarray) -> PreviousFrame:
    return PreviousFrame(orb_features(_texture(), 500), depth, CAMERA)


def _texture() -> np.ndarray:
    return block_texture(HW)


def test_depth_span_is_the_neighbourhood_range() -> None:
    d = np.full((9, 9), 4.0, np.float32)
    d[4, 4] = 2.0
    d[4, 5] = 6.0
    d[0, 8] = 0.0
    lo, hi = depth_span(d)
    assert lo[4, 6] == 2.0 and hi[4, 6] == 6.0 and lo[4, 8] == 4.0 and hi[1, 1] == 4.0
    assert np.isnan(lo[1, 7]) and np.isnan(hi[1, 7])  # a pixel without depth nearby


def test_a_statue_is_unchanged_and_a_walker_is_not_even_with_the_camera_moving() -> None:
    before, _ = _render(0.0)
    now, masks = _render(10 * WALKER_SPEED)
    frac = changed_fractions(now, _earlier(before), _pose(0.0), masks)
    assert frac[0] == 0.0 and frac[1] > 0.5
    # the camera moved 0.2 m: with the pose the statue is still unchanged, without it not
    moved, seen = _render(10 * WALKER_SPEED, cam_x=0.2)
    frac = changed_fractions(moved, _earlier(before), _pose(0.2), seen)
    assert frac[0] <= STILL_FRACTION and frac[1] > 0.5
    assert changed_fractions(moved, _earlier(before), _pose(0.0), seen)[0] > 0.1
    # a walker who only comes 0.5 m nearer (no sideways motion) changed everywhere too (all
    # but the 2-px rim, whose neighbourhood spans the walker and the wall behind)
    near = now.copy()
    near[masks[1]] = WALKER - 0.5
    assert changed_fractions(near, _earlier(now), _pose(0.0), masks[1:])[0] > 0.7
    # one who recedes was hidden behind its own earlier place: undecided, not still
    far = now.copy()
    far[masks[1]] = WALKER + 0.5
    assert np.isnan(changed_fractions(far, _earlier(now), _pose(0.0), masks[1:])[0])


def test_a_walker_passing_in_front_earlier_leaves_a_statue_still() -> None:
    """What hid the statue in the earlier frame is not its motion: those pixels are not
    tested, the rest are unchanged."""
    now, masks = _render(0.0)
    before = now.copy()
    before[20:100, 30:45] = 1.5  # a walker in front of part of the statue then
    frac = changed_fractions(now, _earlier(before), _pose(0.0), masks[:1])
    assert frac[0] == 0.0


def test_too_few_pixels_or_no_depth_leave_it_undecided() -> None:
    before, masks = _render(0.0)
    tiny = np.zeros((1, *HW), bool)
    tiny[50:55, 30:35] = True  # 25 px: 9 grid px, under MIN_TESTED
    assert np.isnan(changed_fractions(before, _earlier(before), _pose(0.0), tiny)[0])
    blank = PreviousFrame(orb_features(_texture(), 500))  # no depth
    assert np.isnan(changed_fractions(before, blank, _pose(0.0), masks)).all()


def test_compared_frames_are_half_and_all_the_window_back() -> None:
    history = [PreviousFrame(orb_features(_texture(), 10)) for _ in range(20)]
    assert compared_frames(history[:9], 20) == ()  # under half the window: no test yet
    assert compared_frames(history, 0) == ()
    got = compared_frames(history, 20)
    assert got[0] is history[-10] and got[1] is history[0]
    early = compared_frames(history[:13], 20)  # from half the window: half and all of it
    assert early[0] is history[7] and early[1] is history[0]  # t - 6 and t - 13


def test_still_objects_needs_a_pose_and_only_judges_candidates() -> None:
    before, _ = _render(0.0)
    now, masks = _render(10 * WALKER_SPEED)
    current = orb_features(_texture(), 500)
    both = np.ones(2, bool)
    got = still_objects(now, current, [_earlier(before)], masks, both)
    assert got.tolist() == [True, False]  # the same image: the pose is the identity
    assert not still_objects(now, current, [_earlier(before)], masks, np.zeros(2, bool)).any()
    other = orb_features(np.random.default_rng(5).integers(0, 256, (*HW, 3), np.uint8), 500)
    assert not still_objects(now, other, [_earlier(before)], masks, both).any()  # no pose


def test_grid_iou_counts_every_second_pixel() -> None:
    a = np.zeros((2, 8, 8), bool)
    a[0, 0:4, 0:4] = True  # 4 grid px
    a[1, 1:2, 1:8] = True  # an odd row: no grid px
    b = np.zeros((1, 8, 8), bool)
    b[0, 0:4, 2:8] = True  # 6 grid px, 2 shared with a[0]
    np.testing.assert_allclose(grid_iou(a, b), [[2 / 8], [0.0]])


def test_a_statue_found_still_stays_still_while_a_walker_brushes_it() -> None:
    """Something nearer over a fifth of the statue now: not still on its own, still when its
    mask matches one found still the frame before; two fifths is too much even then; too
    few pixels tested keeps a remembered verdict."""
    before, masks = _render(0.0)
    current = orb_features(_texture(), 500)
    brushed = before.copy()
    brushed[20:36][masks[0][20:36]] = STATUE - 0.5  # 16 of the statue's 80 rows
    frac = changed_fractions(brushed, _earlier(before), _pose(0.0), masks[:1])[0]
    assert STILL_FRACTION < frac <= STILL_KEEP_FRACTION
    statue = masks[:1]
    one = np.ones(1, bool)
    assert not still_objects(brushed, current, [_earlier(before)], statue, one)[0]
    assert still_objects(brushed, current, [_earlier(before)], statue, one, before=statue)[0]
    shifted = np.roll(statue, 40, axis=2)  # no overlap: not the same object
    assert not still_objects(brushed, current, [_earlier(before)], statue, one, shifted)[0]
    crossed = before.copy()
    crossed[20:56][masks[0][20:56]] = STATUE - 0.5  # 36 of 80 rows
    assert not still_objects(crossed, current, [_earlier(before)], statue, one, statue)[0]
    covered = before.copy()
    covered[masks[0]] = 1.0  # a walker in front of all of it then: hidden, nothing tested
    frames = [_earlier(before), _earlier(covered)]
    assert np.isnan(changed_fractions(before, frames[1], _pose(0.0), statue)[0])
    assert still_objects(before, current, frames, statue, one, statue)[0]  # the verdict stands
    assert not still_objects(before, current, frames, statue, one)[0]  # undecided: dynamic


@pytest.mark.parametrize("still_frames", [20, 0])
def test_through_the_chain_a_statue_is_given_back_from_half_the_window(still_frames: int) -> None:
    """Ground-truth instances of a still camera's sequence: the statue and the walker are
    masked until half the window is there; then only the walker is (with the setting on)."""
    rgb = _texture()
    boxes = np.array([[0, 15, 80, 105], [80, 15, 160, 105]], np.float32)

    def segmenter(image: np.ndarray, stamp: float, conf: float) -> Objects:
        _, masks = _render(WALKER_SPEED * round(stamp * 30))
        return frame_objects(boxes, np.zeros(2, np.int64), masks, HW)

    masking = DEFAULT.with_values(min_static=0, still_frames=still_frames)
    config = ChainConfig(mode=Mode.SEG, masking=masking, camera=CAMERA, fps=30.0)
    with FrameMasker(segmenter, [1.0], config) as masker:
        for i in range(25):
            depth, masks = _render(WALKER_SPEED * i)
            out = masker.step(rgb, depth, stamp=i / 30)
            statue = out.mask[masks[0]] > 0
            walker = out.mask[masks[1]] > 0
            assert walker.mean() > 0.9, i
            if still_frames and i >= still_frames // 2:
                assert not statue.any(), i
                assert out.inputs.still is not None and out.inputs.still.tolist() == [True, False]
            else:
                assert statue.all(), i
                assert out.inputs.still is None or not out.inputs.still.any(), i


def test_the_presets_and_a_missing_key() -> None:
    assert PAPERS.still_frames == 0 and DEFAULT.still_frames == 20
    from slimseg.deploy.metadata import masking_from_metadata

    old = {"slam_masking": {k: v for k, v in DEFAULT.as_dict().items() if k != "still_frames"}}
    assert masking_from_metadata(old).still_frames == 0  # exports before it: off
