"""YOLO-SLAM depth-RANSAC on hand-built depth sets (a person at 2 m before a wall at 4 m)."""

from __future__ import annotations

import numpy as np
import pytest

from slimseg.dynamic.depth_ransac import adaptive_iterations, depth_ransac, screen_box_keypoints


def _person_and_wall(seed: int = 0) -> np.ndarray:
    """``[100]`` depths (m): 60 person points at 2 ± 0.05, then 40 wall points at 4 ± 0.05."""
    g = np.random.default_rng(seed)
    return np.concatenate([2.0 + g.uniform(-0.05, 0.05, 60), 4.0 + g.uniform(-0.05, 0.05, 40)])


def test_person_points_dynamic_wall_static() -> None:
    d = _person_and_wall()
    dyn = depth_ransac(d, rng=np.random.default_rng(1))
    assert dyn[:60].all() and not dyn[60:].any()


def test_invalid_depths_are_never_dynamic() -> None:
    d = _person_and_wall()
    d[[0, 5, 70]] = [0.0, np.nan, np.inf]
    dyn = depth_ransac(d, rng=np.random.default_rng(1))
    assert not dyn[[0, 5, 70]].any()
    assert dyn[1:5].all() and dyn[6:60].all() and not dyn[60:].any()


def test_all_invalid_and_empty() -> None:
    assert depth_ransac(np.array([0.0, np.nan, 0.0, -1.0])).tolist() == [False] * 4
    assert depth_ransac(np.zeros(0)).shape == (0,)
    assert depth_ransac(np.array([0.0, 3.0])).tolist() == [False, True]  # one-point set


def test_deterministic_with_seeded_rng() -> None:
    g = np.random.default_rng(5)
    d = np.concatenate([g.uniform(1.0, 6.0, 50), 2.5 + g.normal(0, 0.1, 30)])
    a = depth_ransac(d, threshold=0.1, rng=np.random.default_rng(3))
    b = depth_ransac(d, threshold=0.1, rng=np.random.default_rng(3))
    assert np.array_equal(a, b) and a[50:].all()


def test_grow_mode_keeps_set_variance_below_threshold() -> None:
    d = _person_and_wall()
    dyn = depth_ransac(d, rng=np.random.default_rng(1), mode="grow")
    assert dyn[:60].all()
    assert np.var(d[dyn]) <= 0.43
    # A set variance is tolerant of a few far points: 60 at 2 m absorb up to 8 at 4 m.
    assert 0 < dyn[60:].sum() <= 8
    assert not depth_ransac(d, threshold=0.01, rng=np.random.default_rng(1), mode="grow")[60:].any()


def test_adaptive_iterations() -> None:
    assert adaptive_iterations(0.5, 0.99, 2) == pytest.approx(np.log(0.01) / np.log(0.75))
    assert adaptive_iterations(0.0, 0.99, 2) > 1e6  # clamped, effectively unbounded
    assert adaptive_iterations(1.0, 0.99, 2) < 1


def test_screen_box_keypoints() -> None:
    h, w = 100, 120
    depth = np.full((h, w), 4.0, np.float32)  # wall
    depth[20:80, 30:60] = 2.0  # person
    depth[50, 90] = 0.0  # a hole in the wall, inside the box
    g = np.random.default_rng(0)
    person = np.stack([g.uniform(31, 58, 40), g.uniform(21, 78, 40)], 1)
    wall_in_box = np.stack([g.uniform(62, 88, 15), g.uniform(21, 78, 15)], 1)
    hole = np.array([[90.0, 50.0]])
    outside = np.array([[5.0, 5.0], [110.0, 90.0], [40.0, 95.0], [-3.0, 50.0]])
    kp = np.concatenate([person, wall_in_box, hole, outside])
    boxes = np.array([[25.0, 15.0, 95.0, 85.0]])
    dyn = screen_box_keypoints(kp, depth, boxes, rng=np.random.default_rng(0))
    assert dyn[:40].all()
    assert not dyn[40:].any()
    assert not screen_box_keypoints(kp, depth, np.zeros((0, 4))).any()
    assert screen_box_keypoints(np.zeros((0, 2)), depth, boxes).shape == (0,)
