"""The degrading masking rule: less certain masks go first, a confident mover never does, and
static support counts the corners left outside the mask (docs/slam_defaults.md §1)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from conftest import frame_objects

from slimseg.dynamic.degrade import degrade, support_points
from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.masking_settings import PAPERS, PRESETS, SLIMSEG, SettingsError
from slimseg.dynamic.pipeline import FrameRules, process_frame

HW = (60, 80)
MOBILITY = np.array([1.0], np.float32)  # one class: person


def _grid(step: int) -> np.ndarray:
    ys, xs = np.mgrid[1 : HW[0] : step, 1 : HW[1] : step]
    return np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float32)


def _scene() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A confident walker, a low-score blob over most of the wall, a mid-score small blob."""
    walker = np.zeros(HW, bool)
    walker[10:50, 5:20] = True
    blob = np.zeros(HW, bool)
    blob[:, 25:80] = True
    small = np.zeros(HW, bool)
    small[0:8, 0:24] = True
    masks = np.stack([walker, blob, small])
    boxes = np.array([[5, 10, 20, 50], [25, 0, 80, 60], [0, 0, 24, 8]], np.float32)
    scores = np.array([0.9, 0.12, 0.3], np.float32)
    return masks, boxes, scores, np.zeros(3, np.int64)


def _run(rule: str, min_static: int, support: np.ndarray | None = None, scores=None):
    masks, boxes, s, classes = _scene()
    scores = s if scores is None else scores
    inputs = FrameInputs(
        _grid(4), frame_objects(boxes, classes, masks, HW, scores), support=support
    )
    rules = FrameRules(MOBILITY, "seg", PAPERS.with_values(min_static=min_static, rule=rule))
    return process_frame(inputs=inputs, settings=rules)


def _on_walker(kps: np.ndarray) -> np.ndarray:
    return (kps[:, 0] >= 5) & (kps[:, 0] < 20) & (kps[:, 1] >= 10) & (kps[:, 1] < 50)


def test_eq1_gives_up_the_walker_where_degrade_drops_the_blob() -> None:
    kps = _grid(4)
    # 300 keypoints; 37 % lie outside the three masks: too few for min_static 120
    eq1 = _run("eq1", 120)
    assert eq1.m_th is None and not eq1.dynamic.any()  # the walker's points go to SLAM
    assert eq1.dropped == [0, 1, 2]
    deg = _run("degrade", 120)
    assert deg.dropped == [1]  # only the least certain (0.12 x 1.0) went
    assert deg.dynamic[_on_walker(kps)].all()
    assert deg.support >= 120 and deg.m_th == PAPERS.m_th_start
    assert (deg.mask[15, 10], deg.mask[2, 2], deg.mask[30, 60]) == (255, 255, 0)


def test_degrade_stops_as_soon_as_support_suffices() -> None:
    assert _run("degrade", 10).dropped == []  # enough support: nothing given up
    assert _run("degrade", 260).dropped == [1, 2]  # least certain first, then the next


def test_a_confident_mover_is_never_given_up() -> None:
    r = _run("degrade", 10_000)  # support can never suffice
    assert r.dropped == [1, 2] and r.dynamic[_on_walker(_grid(4))].all()
    assert r.support < 10_000
    # raise every score over keep_score: nothing may go
    assert _run("degrade", 10_000, scores=np.full(3, 0.6, np.float32)).dropped == []


def test_support_counts_the_corners_outside_the_mask_not_the_keypoints() -> None:
    # a densely textured strip between walker and blob: 268 corners outside the masks, while
    # only 111 of the 300 keypoints are (too few for Eq. 1 at min_static 120)
    ys, xs = np.mgrid[0 : HW[0], 20:25]
    strip = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float32)
    r = _run("degrade", 120, support=strip)
    assert r.dropped == [] and r.support == 268
    assert _run("eq1", 120).m_th is None
    r = _run("degrade", 120, support=np.zeros((0, 2), np.float32))
    assert r.dropped == [1, 2] and r.support == 0  # no corners at all: all uncertain masks go


def test_equal_certainty_drops_the_larger_region_then_the_later_detection_first() -> None:
    masks, _, _, _ = _scene()
    masks = masks[[2, 1, 0]]  # small, blob, walker
    same = {"mobility": np.ones(3, np.float32), "scores": np.array([0.2, 0.2, 0.2]),
            "keypoints": _grid(4), "support": _grid(4), "m_th_start": 0.25}  # fmt: skip
    assert degrade(regions=masks, min_static=130, **same).dropped == [1]  # the blob
    twins = np.stack([masks[2], masks[2]])  # equal areas too: the later one
    assert degrade(regions=twins, min_static=300, **{**same, "mobility": np.ones(2),
                   "scores": np.array([0.2, 0.2])}).dropped == [1, 0]  # fmt: skip


def test_support_points_find_corners_of_a_textured_frame() -> None:
    img = (np.random.default_rng(0).random((64, 64)) * 255).astype(np.uint8)
    pts = support_points(img)
    assert pts.dtype == np.float32 and pts.shape[1] == 2 and len(pts) >= 20
    assert len(support_points(np.zeros((64, 64, 3), np.uint8))) == 0


def test_presets_and_settings() -> None:
    assert (PAPERS.rule, SLIMSEG.rule) == ("eq1", "degrade")
    assert set(PRESETS) == {"papers", "slimseg"}
    assert "rule degrade" in SLIMSEG.describe()
    with pytest.raises(SettingsError, match="rule = 'nope'"):
        SLIMSEG.with_values(rule="nope")
    with pytest.raises(SettingsError, match="keep_score"):
        SLIMSEG.with_values(keep_score=1.5)


def test_cli_refuses_an_unknown_rule_in_one_line(tmp_path) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "slimseg", "dynamic", "--sequence", str(tmp_path),
         "--model", str(tmp_path / "m.onnx"), "--set", "rule=sometimes"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert r.returncode == 2
    assert "rule" in r.stderr and "Traceback" not in r.stderr
