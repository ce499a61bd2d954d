"""The depth cut's motion layers: what moved in behind an object's near layer stays."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import block_texture, frame_objects, sideways_pose

from slimseg.dynamic.epipolar import PnpPose, PreviousFrame, orb_features
from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.masking_settings import DEFAULT, PAPERS
from slimseg.dynamic.occupancy import (
    STRIDE,
    camera_pose,
    motion_layers,
    moved_in,
    nearest_before,
)
from slimseg.dynamic.pipeline import FrameRules, process_frame

HW = (120, 160)
CAMERA = (100.0, 100.0, 79.5, 59.5)
WALL, WALKER, TABLE = 5.0, 3.0, 1.5


def _pose(tx: float = 0.0) -> PnpPose:
    return sideways_pose(CAMERA, tx)


def _scene(walker_x: int, table: bool = True, box_x: int = 0) -> np.ndarray:
    """``float32 [H, W]``: a wall, a walker (rows 20-100, 20 px wide from ``walker_x``) and,
    nearer, a table over the lower rows (``box_x``: a static box's column shift)."""
    d = np.full(HW, WALL, np.float32)
    d[20:100, walker_x : walker_x + 20] = WALKER
    if table:
        d[70:110, 30 + box_x : 130 + box_x] = TABLE
    return d


def test_nearest_before_is_the_neighbourhood_minimum() -> None:
    d = np.full((9, 9), 4.0, np.float32)
    d[4, 4] = 2.0
    d[0, 8] = 0.0  # no depth: NaN around it
    near = nearest_before(d)
    assert near[2, 2] == 2.0 and near[4, 6] == 2.0 and near[4, 7] == 4.0
    assert np.isnan(near[0, 6]) and np.isnan(near[2, 8])


def test_a_walker_moving_in_is_marked_and_a_static_scene_is_not() -> None:
    every = np.ones(HW, bool)
    still = moved_in(_scene(60), nearest_before(_scene(60)), CAMERA, _pose(), every)
    assert still.shape == (HW[0] // STRIDE, HW[1] // STRIDE) and not still.any()
    # the walker stepped 10 px right: its leading 10 px were wall before; after the opening
    # of the neighbourhood (2 px) 8 px of them stay, on the grid every other column
    moved = moved_in(_scene(70), nearest_before(_scene(60)), CAMERA, _pose(), every)
    ys, xs = np.nonzero(moved)
    assert set((xs * STRIDE).tolist()) == {82, 84, 86, 88}
    assert ys.min() * STRIDE >= 20 and ys.max() * STRIDE < 100
    # the trailing edge (wall now where the walker was) is not marked: it was nearer before
    assert not moved[:, : 70 // STRIDE].any()


def test_the_camera_own_motion_marks_nothing() -> None:
    """A sideways camera: every surface shifts by fx * tx / z px; the pose explains it, the
    surfaces it uncovers were hidden (nearer before), so nothing is marked."""
    tx = 0.06  # the table shifts 4 px, the walker 2 px, the wall 1.2 px
    before = np.full(HW, WALL, np.float32)
    before[20:100, 62:82] = WALKER
    before[70:110, 34:134] = TABLE
    now = np.full(HW, WALL, np.float32)
    now[20:100, 60:80] = WALKER
    now[70:110, 30:130] = TABLE
    got = moved_in(now, nearest_before(before), CAMERA, _pose(tx), np.ones(HW, bool))
    assert not got.any()
    # without the pose the same frames mark the surfaces' edges
    assert moved_in(now, nearest_before(before), CAMERA, _pose(), np.ones(HW, bool)).any()


def test_the_layer_is_the_median_of_marked_pixels_behind_the_near_layer() -> None:
    depth = _scene(70)
    marked = moved_in(depth, nearest_before(_scene(60)), CAMERA, _pose(), np.ones(HW, bool))
    boxes = np.array([[20, 10, 140, 115], [0, 0, 10, 10]], np.float32)
    ref = np.array([TABLE, np.nan], np.float32)
    lay = motion_layers(marked, boxes, depth, ref, 0.5, 100)
    assert lay[0] == WALKER and np.isnan(lay[1])
    assert np.isnan(motion_layers(marked, boxes, depth, ref, 0.5, 10_000)[0])  # too few
    # the walker at the near layer itself is not behind it: no layer
    assert np.isnan(motion_layers(marked, boxes, depth, np.array([WALKER, 0]), 0.5, 100)[0])


def _texture(seed: int = 0) -> np.ndarray:
    return block_texture(HW, seed)


def test_camera_pose_of_a_still_camera_is_the_identity() -> None:
    rgb = _texture()
    f = orb_features(rgb, 500)
    depth = np.full(HW, WALL, np.float32)
    depth[:, :80] = 3.0  # two planes: not a degenerate single plane
    pose = camera_pose(PreviousFrame(f, depth, CAMERA), f)
    assert pose is not None
    np.testing.assert_allclose(pose.tvec.ravel(), 0, atol=1e-3)
    np.testing.assert_allclose(pose.rotation, np.eye(3), atol=1e-3)
    assert camera_pose(PreviousFrame(f), f) is None  # no depth, no intrinsics: no pose


@pytest.mark.parametrize("layer_px", [100, 0])
def test_a_walker_behind_a_table_keeps_its_mask_where_it_moved(layer_px: int) -> None:
    """The coarse mask covers the table in front (its near layer) and the walker behind it;
    the cut alone drops the walker, the motion layer keeps it; the wall stays cut."""
    rgb = _texture(1)
    features = orb_features(rgb, 500)
    before, now = _scene(60), _scene(70)
    box = np.array([[25, 15, 135, 112]], np.float32)
    mask = np.zeros((1, *HW), bool)
    mask[0, 15:112, 25:135] = True
    # the chain's own keypoints and descriptors: the pose is fitted on their matches
    inputs = FrameInputs(
        features.keypoints, frame_objects(box, np.zeros(1, np.int64), mask, HW), depth_m=now,
        descriptors=features.descriptors, previous=PreviousFrame(features, before, CAMERA),
    )  # fmt: skip
    settings = DEFAULT.with_values(min_static=0, motion_layer_px=layer_px)
    rules = FrameRules(np.array([1.0], np.float32), "seg", settings)
    res = process_frame(inputs=inputs, settings=rules)
    walker = res.mask[30:65, 72:88]
    assert res.mask[80:105, 40:120].all()  # the table, the near layer
    assert not res.mask[20:60, 30:60].any()  # the wall
    if layer_px:
        assert walker.all()
    else:
        assert not walker.any()


def test_the_presets_and_a_missing_key() -> None:
    assert PAPERS.motion_layer_px == 0 and DEFAULT.motion_layer_px == 100
    from slimseg.deploy.metadata import masking_from_metadata

    old = {"slam_masking": {k: v for k, v in DEFAULT.as_dict().items() if k != "motion_layer_px"}}
    assert masking_from_metadata(old).motion_layer_px == 0  # exports before it: off


def test_slivers_and_depth_edges_are_not_surfaces() -> None:
    """A 2-px chair leg flickers in a depth image: it is never a candidate."""
    from slimseg.dynamic.occupancy import surfaces

    d = np.full(HW, WALL, np.float32)
    d[10:60, 40:42] = WALKER  # a 2-px leg
    d[10:60, 80:100] = WALKER  # a 20-px body
    d[100:110, 10:20] = 0.0  # no depth
    s = surfaces(d)
    assert not s[10:60, 40:42].any() and not s[10:60, 39].any()  # the leg and its edge
    assert s[12:58, 81:99].all() and not s[30, 79:81].any()  # the body inside, not its edge
    assert s[30, 60] and not s[105, 15]
