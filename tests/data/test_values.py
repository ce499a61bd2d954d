"""Every value checked where it is read (issue 47, class 3): poses, trajectories that cannot
be aligned, intrinsics, frame sizes within a sequence and frames without depth."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from slimseg.data.bags.poses import degenerate, ground_truth
from slimseg.data.synth.sequence import write_sequence
from slimseg.data.tum import TumSequence, read_camera, read_trajectory
from slimseg.data.value_checks import check_intrinsics, check_pose
from slimseg.errors import SlimsegError
from slimseg.slam.metrics import score


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("values") / "seq"
    write_sequence(folder, 0, 0, 4, (64, 48))
    return folder


def _copy(seq: Path, tmp_path: Path) -> Path:
    out = tmp_path / "seq"
    shutil.copytree(seq, out)
    return out


@pytest.mark.parametrize(
    ("q", "ok"),
    [((0, 0, 0, 1), True), ((0, 0, 0, 0.6), True), ((0, 0, 0, 0), False), ((0, 0, 0.3, 0), False),
     ((np.nan, 0, 0, 1), False), ((0, 0, 0, 3), False), ((1e-300, 0, 0, 1e-300), False)],
)  # fmt: skip
def test_quaternions_of_usable_norm(q: tuple[float, ...], ok: bool) -> None:
    row = [1.0, 0.0, 0.0, 0.0, *q]
    if ok:
        check_pose(row, "x")
    else:
        with pytest.raises(SlimsegError, match=r"^gt\.txt:7: "):
            check_pose(row, "gt.txt:7")
    with pytest.raises(SlimsegError, match="not finite"):
        check_pose([1.0, np.inf, 0, 0, 0, 0, 0, 1], "x")


def test_trajectories_that_cannot_be_aligned(seq: Path, tmp_path: Path) -> None:
    gt = read_trajectory(seq / "groundtruth.txt")
    assert degenerate(gt[:, 1:4]) == ""
    assert "2 distinct positions" in degenerate(np.array([[0, 0, 0], [1, 0, 0], [0, 0, 0.0]]))
    line = np.outer(np.arange(5.0), [1.0, 2.0, 3.0])
    assert "one line" in degenerate(line)
    still = _copy(seq, tmp_path)
    rows = gt.copy()
    rows[:, 1:4] = 0.5
    text = "\n".join(" ".join(f"{v:.9f}" for v in r) for r in rows)
    (still / "groundtruth.txt").write_text(text + "\n")
    with pytest.raises(SlimsegError, match=r"groundtruth\.txt: the ground truth has 1 distinct"):
        ground_truth(still)
    pytest.importorskip("evo")
    est = gt.copy()
    est[:, 1:4] = 0.0  # an engine that never moved: no alignment, no ATE; the run fails
    with pytest.raises(SlimsegError, match="the estimate has 1 distinct position"):
        score(gt, est, 30.0)
    est[1, 5] = np.nan
    with pytest.raises(SlimsegError, match="pose 2 is not finite"):
        score(gt, est, 30.0)


@pytest.mark.parametrize("fx", ["1.0e-300", "1.0e+12", "0.5"])
def test_implausible_intrinsics(seq: Path, tmp_path: Path, fx: str) -> None:
    cam = tmp_path / "camera.yaml"
    cam.write_text((seq / "camera.yaml").read_text().replace("fx: ", f"fx: {fx}\n#", 1))
    with pytest.raises(SlimsegError, match=r"camera\.yaml: fx = .* px is outside 1\.\.100000"):
        read_camera(cam)
    check_intrinsics({"fx": 500.0, "cy": 1.0}, "x")


def test_a_frame_of_another_size_is_named(seq: Path, tmp_path: Path) -> None:
    folder = _copy(seq, tmp_path)
    s = TumSequence(folder)
    s.load(0)
    (_, rgb), (_, depth) = s.frames[2]
    for rel, dtype in ((rgb, np.uint8), (depth, np.uint16)):
        img = cv2.imread(str(folder / rel), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(folder / rel), np.zeros((img.shape[0] + 2, *img.shape[1:]), dtype))
    s.load(1)
    with pytest.raises(SlimsegError, match=rf"{rgb}: 64x50 px, but .* is 64x48"):
        s.load(2)


def test_a_frame_without_depth_is_named_once(seq: Path, tmp_path: Path, caplog) -> None:
    folder = _copy(seq, tmp_path)
    for k in (1, 3):
        (_, depth) = TumSequence(folder).frames[k][1]
        cv2.imwrite(str(folder / depth), np.zeros((48, 64), np.uint16))
    s = TumSequence(folder)
    with caplog.at_level(logging.WARNING):
        for i in range(len(s)):
            s.load(i)
    warned = [r.getMessage() for r in caplog.records if "no valid depth" in r.getMessage()]
    assert len(warned) == 1 and s.frames[1][0][1] in warned[0], warned
    assert len(s._frames_seen.no_depth) == 2


def test_a_bag_frame_of_another_size_is_named(seq: Path, tmp_path: Path, monkeypatch) -> None:
    pytest.importorskip("rosbags")
    from slimseg.data.bags.from_tum import tum_to_bag
    from slimseg.data.bags.sequence import BagSequence

    real = TumSequence.load

    def grown(self: TumSequence, i: int):  # frame 2 recorded at another size
        rgb, depth, t = real(self, i)
        if i == 2:
            rgb, depth = np.pad(rgb, ((0, 2), (0, 0), (0, 0))), np.pad(depth, ((0, 2), (0, 0)))
        return rgb, depth, t

    monkeypatch.setattr(TumSequence, "load", grown)
    bag = tmp_path / "s.mcap"
    tum_to_bag(seq, bag, camera_info=False)
    with BagSequence(bag) as s:
        s.load(0)
        s.load(1)
        with pytest.raises(SlimsegError, match=r"s\.mcap at .* s: 64x50 px, but .* is 64x48"):
            s.load(2)
