"""TUM RGB-D reader: list parsing, association, synthetic sequences, error messages."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from slimseg.data.synth import generate
from slimseg.data.tum import (
    TUM_FR1,
    TumSequence,
    associate,
    mask_name,
    read_camera,
    read_list,
    read_trajectory,
)
from slimseg.errors import SlimsegError


@pytest.fixture(scope="module")
def synth_seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth")
    generate(out, 1, 1, 64, 0, sequences=1, frames=4, seq_size=(160, 120), progress=False)
    return out / "sequences" / "seq_000"


def test_read_list_skips_comments_and_blank_lines(tmp_path: Path) -> None:
    p = tmp_path / "rgb.txt"
    p.write_text("# color images\n# timestamp filename\n\n1.000000 rgb/1.png\n  2.5 rgb/2.png  \n")
    assert read_list(p) == [(1.0, "rgb/1.png"), (2.5, "rgb/2.png")]


def test_read_list_malformed_line_names_file_and_line(tmp_path: Path) -> None:
    p = tmp_path / "depth.txt"
    p.write_text("# c\n1.0 depth/1.png\nabc depth/2.png\n")
    with pytest.raises(SlimsegError, match=r"depth\.txt:3"):
        read_list(p)
    p.write_text("1.0\n")
    with pytest.raises(SlimsegError, match=r"depth\.txt:1"):
        read_list(p)
    with pytest.raises(SlimsegError, match=r"missing\.txt"):
        read_list(tmp_path / "missing.txt")


def test_associate_offsets_and_unmatched() -> None:
    rgb = [(10.0 + i / 30, f"rgb/{i}.png") for i in range(5)]
    depth = [(t + 0.005, f"depth/{i}.png") for i, (t, _) in enumerate(rgb)]
    # depth 3 lies 0.025 s after rgb 3 (too far) and 0.008 s before rgb 4, which depth 4 is
    # closer to (0.005 s): rgb 3 and depth 3 stay unmatched.
    depth[3] = (rgb[3][0] + 0.025, "depth/3.png")
    depth.reverse()  # order of the input lists does not matter
    pairs = associate(rgb, depth)
    assert [(r[1], d[1]) for r, d in pairs] == [
        ("rgb/0.png", "depth/0.png"),
        ("rgb/1.png", "depth/1.png"),
        ("rgb/2.png", "depth/2.png"),
        ("rgb/4.png", "depth/4.png"),
    ]
    assert pairs.unmatched_rgb == 1 and pairs.unmatched_depth == 1
    assert all(abs(r[0] - d[0]) <= 0.02 for r, d in pairs)


def test_associate_uses_each_depth_once() -> None:
    rgb = [(0.0, "a"), (0.01, "b")]
    depth = [(0.008, "d")]
    pairs = associate(rgb, depth)
    assert [(r[1], d[1]) for r, d in pairs] == [("b", "d")]
    assert pairs.unmatched_rgb == 1 and pairs.unmatched_depth == 0
    assert associate([], depth) == [] and associate(rgb, []).unmatched_rgb == 2


def test_synth_sequence_loads_in_metres(synth_seq: Path) -> None:
    seq = TumSequence(synth_seq)
    assert len(seq.frames) == 4 and len(seq) == 4
    assert seq.camera.depth_scale == 5000.0 and seq.camera.fx > 0
    rgb, depth, t = seq.load(0)
    assert rgb.dtype == np.uint8 and rgb.shape == (120, 160, 3)
    assert depth.dtype == np.float32 and depth.shape == (120, 160)
    valid = depth[depth > 0]
    assert valid.size > 0.5 * depth.size
    assert valid.min() >= 0.3 and valid.max() <= 10.0
    assert t == seq.frames[0][0][0]
    assert mask_name(t) in {p.name for p in (synth_seq / "dynamic").iterdir()}
    assert mask_name(t) == Path(seq.frames[0][0][1]).name
    gt = read_trajectory(synth_seq / "groundtruth.txt")
    assert gt.shape == (4, 8) and np.allclose(np.linalg.norm(gt[:, 4:], axis=1), 1, atol=1e-4)


def test_camera_defaults_without_yaml(synth_seq: Path, tmp_path: Path) -> None:
    root = tmp_path / "seq"
    root.mkdir()
    for name in ("rgb.txt", "depth.txt"):
        (root / name).write_text((synth_seq / name).read_text())
    seq = TumSequence(root)
    assert (seq.camera.fx, seq.camera.cy, seq.camera.depth_scale) == (
        TUM_FR1["fx"],
        TUM_FR1["cy"],
        5000.0,
    )
    with pytest.raises(SlimsegError, match=r"missing image file .*rgb"):
        seq.load(0)


def test_size_mismatch_names_both_files(synth_seq: Path, tmp_path: Path) -> None:
    seq = TumSequence(synth_seq)
    depth_rel = seq.frames[1][1][1]
    path = synth_seq / depth_rel
    original = path.read_bytes()
    try:
        cv2.imwrite(str(path), np.full((60, 80), 10000, np.uint16))
        with pytest.raises(SlimsegError, match="size mismatch") as e:
            seq.load(1)
        assert seq.frames[1][0][1] in str(e.value) and depth_rel in str(e.value)
    finally:
        path.write_bytes(original)


def test_empty_and_missing_sequences(tmp_path: Path) -> None:
    with pytest.raises(SlimsegError, match=r"rgb\.txt"):
        TumSequence(tmp_path)
    (tmp_path / "rgb.txt").write_text("# only comments\n")
    (tmp_path / "depth.txt").write_text("1.0 depth/1.png\n")
    with pytest.raises(SlimsegError, match="empty"):
        TumSequence(tmp_path)
    with pytest.raises(SlimsegError, match="does not exist"):
        TumSequence(tmp_path / "nope")


def test_read_groundtruth_malformed(tmp_path: Path) -> None:
    p = tmp_path / "groundtruth.txt"
    p.write_text("# gt\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n")
    with pytest.raises(SlimsegError, match=r"groundtruth\.txt:3"):
        read_trajectory(p)


ORB_SLAM3_SETTINGS = """%YAML:1.0
File.version: "1.0"
Camera.type: "PinHole"
Camera1.fx: 535.4
Camera1.fy: 539.2
Camera1.cx: 320.1
Camera1.cy: 247.6
Camera1.k1: 0.0
Camera.width: 640
Camera.fps: 30
Stereo.ThDepth: 40.0
RGBD.DepthMapFactor: 5000.0
ORBextractor.nFeatures: 1000
"""


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("fX: 600\n", "unknown key 'fX' (did you mean fx?)"),
        ("depth_scal: 1000\n", "did you mean depth_scale?"),
        ("Camera.FX: 600\n", "did you mean Camera.fx?"),
        ("colour: 1\n", "unknown key 'colour'"),
        ("fx: 0.0\n", "fx must be a number > 0, got 0.0"),
        ("cy: .nan\n", "cy must be a number > 0"),
        ("fx: yes\n", "fx must be a number > 0, got True"),
        ("fx: 1\nCamera.fx: 2\n", "fx given twice"),
    ],
)
def test_camera_file_is_read_strictly(tmp_path: Path, text: str, needle: str) -> None:
    (tmp_path / "camera.yaml").write_text(text)
    with pytest.raises(SlimsegError, match=r"camera\.yaml") as e:
        read_camera(tmp_path / "camera.yaml")
    assert needle in str(e.value)


def test_orbslam_settings_file_is_a_camera_file(tmp_path: Path) -> None:
    (tmp_path / "camera.yaml").write_text(ORB_SLAM3_SETTINGS)
    assert read_camera(tmp_path / "camera.yaml") == {
        "fx": 535.4, "fy": 539.2, "cx": 320.1, "cy": 247.6, "depth_scale": 5000.0
    }  # fmt: skip


def test_depth_must_be_16_bit_at_a_plausible_scale(synth_seq: Path, tmp_path: Path) -> None:
    seq = Path(shutil.copytree(synth_seq, tmp_path / "s"))
    first = seq / TumSequence(seq).frames[0][1][1]
    raw = cv2.imread(str(first), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(first), (raw // 256).astype(np.uint8))
    with pytest.raises(SlimsegError, match=r"is uint8, expected a 16-bit PNG"):
        TumSequence(seq).load(0)
    cv2.imwrite(str(first), raw)
    (seq / "camera.yaml").write_text("depth_scale: 5\n")  # metres x 1000 read as x 5
    with pytest.raises(SlimsegError, match=r"median depth .* outside 0.05-100.0 m"):
        TumSequence(seq).load(0)


@pytest.mark.parametrize(
    ("pose", "needle"),
    [
        ("nan 0 0 0 0 0 1", "not finite"),
        ("0 0 0 0 0 0 0", "has norm 0"),
        ("0 0 0 inf 0 0 1", ""),
    ],
)
def test_trajectory_poses_are_finite_rotations(tmp_path: Path, pose: str, needle: str) -> None:
    p = tmp_path / "groundtruth.txt"
    p.write_text(f"# gt\n1 0 0 0 0 0 0 1\n2 {pose}\n")
    with pytest.raises(SlimsegError, match=r"groundtruth\.txt:3") as e:
        read_trajectory(p)
    assert needle in str(e.value)


def test_mask_name() -> None:
    assert mask_name(1305031102.175304) == "1305031102.175304.png"
    assert mask_name("1305031102.1753") == "1305031102.1753.png"
