"""slam-eval: evo's ATE/RPE against hand computations, intrinsics by folder name, the DBoW2
vocabulary builder loading in ORB-SLAM3, bad input, and one short end-to-end run."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from slimseg.cli.main import main
from slimseg.data.synth import generate
from slimseg.data.synth.world import build_world
from slimseg.data.tum import CALIBRATIONS, TumSequence, calibration_for
from slimseg.errors import SlimsegError
from slimseg.slam.metrics import score, still_floor
from slimseg.slam.trajectory import matrix_to_tum, quat_to_matrix, tum_to_matrices
from slimseg.slam.vocab import build_vocabulary, check_vocabulary

pytest.importorskip("evo", reason="the [slam] extra (make test installs it)")


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _helix(n: int = 80) -> np.ndarray:
    """TUM rows of a camera on a helix, turning as it goes (30 Hz)."""
    rows = []
    for i in range(n):
        t = i / 30
        pose = np.eye(4)
        pose[:3, :3] = _rot([0.2, 1, 0.1], 0.4 * t)
        pose[:3, 3] = [0.5 * np.cos(t), 0.3 * t, 0.5 * np.sin(t)]
        rows.append(matrix_to_tum(100.0 + t, pose))
    return np.array(rows)


def _kabsch_rmse(p: np.ndarray, q: np.ndarray) -> float:
    """RMSE of ``q`` after the least-squares rigid motion mapping it onto ``p``."""
    pc, qc = p - p.mean(0), q - q.mean(0)
    u, _, vt = np.linalg.svd(qc.T @ pc)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1, 1, d]) @ u.T
    return float(np.sqrt(((qc @ r.T - pc) ** 2).sum(1).mean()))


def test_ate_and_rpe_equal_hand_computations() -> None:
    gt = _helix()
    rng = np.random.default_rng(0)
    offset = np.eye(4)
    offset[:3, :3] = _rot([1, -0.5, 0.3], 0.7)
    offset[:3, 3] = [2.0, -1.0, 0.5]
    poses = np.einsum("ij,kjl->kil", offset, tum_to_matrices(gt))  # a rigidly moved copy
    poses[:, :3, 3] += rng.normal(0, 0.01, (len(gt), 3))
    est = np.array([matrix_to_tum(t, p) for t, p in zip(gt[:, 0] + 0.004, poses, strict=True)])
    s = score(gt, est, fps=30)
    assert s.matched == len(gt)
    hand = _kabsch_rmse(gt[:, 1:4], poses[:, :3, 3])
    assert s.ate_rmse == pytest.approx(hand, rel=1e-6)
    assert 0.01 < s.ate_rmse < 0.025  # the noise, not the 2 m offset
    # RPE translation over 1 frame: ||trans((Q_i^-1 Q_j)^-1 (P_i^-1 P_j))||, RMSE over pairs
    q, p = tum_to_matrices(gt), poses
    err = [
        np.linalg.norm((np.linalg.inv(np.linalg.inv(q[i]) @ q[i + 1]) @
                        (np.linalg.inv(p[i]) @ p[i + 1]))[:3, 3])
        for i in range(len(gt) - 1)
    ]  # fmt: skip
    assert s.rpe_trans_frame == pytest.approx(float(np.sqrt(np.mean(np.square(err)))), rel=1e-6)


def test_every_rpe_sees_the_whole_trajectory() -> None:
    """evo's rpe shrinks its inputs to the pairs' poses: each delta must get fresh copies
    (36 poses, 1 s = 30 frames: the rotation's 1 s pairs once failed on the shrunk copy)."""
    gt = _helix(36)
    est = gt.copy()
    est[:, 1] += 0.002 * np.arange(36)  # drift along x: 0.06 m per second, no rotation error
    s = score(gt, est, fps=30)
    assert s.rpe_trans_s == pytest.approx(0.06, rel=1e-6)
    assert s.rpe_trans_frame == pytest.approx(0.002, rel=1e-6)
    assert s.rpe_rot_s == pytest.approx(0.0, abs=1e-6)


def test_still_floor_is_the_best_aligned_standing_camera() -> None:
    gt = _helix()
    centroid = gt[:, 1:4].mean(0)
    expected = np.sqrt(((gt[:, 1:4] - centroid) ** 2).sum(1).mean())
    assert still_floor(gt) == pytest.approx(expected)
    shifted = gt[:, 1:4].mean(0) + np.array([0.01, 0, 0])  # any other spot is worse
    assert np.sqrt(((gt[:, 1:4] - shifted) ** 2).sum(1).mean()) > still_floor(gt)


def test_quaternion_round_trip() -> None:
    for angle in (0.1, 2.0, 3.1):
        r = _rot([0.3, -1, 2], angle)
        row = matrix_to_tum(0.0, np.block([[r, np.zeros((3, 1))], [np.zeros((1, 3)), 1]]))
        assert np.allclose(quat_to_matrix(row[4:8]), r, atol=1e-9)


def _tum_folder(root: Path, name: str, camera: str | None = None) -> Path:
    folder = root / name
    folder.mkdir(parents=True)
    (folder / "rgb.txt").write_text("1.0 rgb/1.png\n")
    (folder / "depth.txt").write_text("1.001 depth/1.png\n")
    if camera:
        (folder / "camera.yaml").write_text(camera)
    return folder


def test_intrinsics_are_picked_by_folder_name(tmp_path: Path) -> None:
    cases = {
        "rgbd_dataset_freiburg3_walking_xyz": "tum-fr3",
        "rgbd_dataset_freiburg2_desk": "tum-fr2",
        "rgbd_dataset_freiburg1_xyz": "tum-fr1",
        "rgbd_bonn_balloon": "bonn",
    }
    for name, key in cases.items():
        seq = TumSequence(_tum_folder(tmp_path, name))
        assert seq.camera_source == f"{key} (folder name)"
        assert (seq.camera.fx, seq.camera.cy) == (CALIBRATIONS[key]["fx"], CALIBRATIONS[key]["cy"])
        assert seq.camera.depth_scale == 5000.0
    assert seq.camera.fx == pytest.approx(542.822841)
    fr3 = TumSequence(tmp_path / "rgbd_dataset_freiburg3_walking_xyz").camera
    assert (fr3.fx, fr3.fy, fr3.cx, fr3.cy) == (535.4, 539.2, 320.1, 247.6)
    plain = TumSequence(_tum_folder(tmp_path, "my_recording"))
    assert plain.camera_source == "tum-fr1 (default)" and plain.camera.fx == 517.3
    line = "intrinsics: fx 517.3, fy 516.5, cx 318.6, cy 255.3 from tum-fr1 (the default: no "
    assert plain.describe_camera().startswith(line)  # what slimseg dynamic prints
    own = TumSequence(_tum_folder(tmp_path, "x/rgbd_dataset_freiburg3_sitting", "fx: 600\n"))
    assert own.camera_source == "camera.yaml (fx), the rest tum-fr3 (folder name)"
    assert (own.camera.fx, own.camera.cx) == (600.0, 320.1)  # the rest: the folder's camera
    assert own.describe_camera().endswith(f"from {own.root / 'camera.yaml'} (fx), the rest "
                                          "tum-fr3 (folder name)")  # fmt: skip
    full = "fx: 600\nfy: 601\ncx: 300\ncy: 200\n"
    own = TumSequence(_tum_folder(tmp_path, "x/rgbd_dataset_freiburg2_own", full))
    assert own.camera_source == "camera.yaml" and own.camera.cy == 200.0
    assert own.describe_camera().endswith(f"from {own.root / 'camera.yaml'}")
    assert calibration_for("fr2_pioneer") == "tum-fr2" and calibration_for("frames") is None


def test_presets_move_the_camera_like_tum() -> None:
    def extent(preset: str) -> np.ndarray:
        w = build_world(0, 0, 300, 320, 240, preset=preset)
        xyz = np.array([[w.pose(i).x, w.pose(i).y, w.pose(i).z] for i in range(300)])
        return np.ptp(xyz, 0), sum(t.moving for t in w.things)

    (xyz_ext, walkers), (still_ext, _) = extent("walking_xyz"), extent("walking_static")
    assert xyz_ext[0] > 0.4 and xyz_ext[1] > 0.1 and xyz_ext[2] > 0.2 and walkers >= 2
    assert still_ext.max() < 0.04
    with pytest.raises(SlimsegError, match="preset"):
        build_world(0, 0, 10, preset="walking_fast")


@pytest.fixture(scope="module")
def xyz_seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("slam") / "data"
    generate(out, 1, 1, 64, 0, sequences=1, frames=60, seq_size=(320, 240), progress=False,
             preset="walking_xyz")  # fmt: skip
    return out / "sequences" / "seq_000"


@pytest.fixture(scope="module")
def vocab(xyz_seq: Path) -> Path:
    paths = sorted((xyz_seq / "rgb").glob("*.png"))[::3]
    out = xyz_seq.parent.parent / "voc.txt"
    info = build_vocabulary(paths, out, k=6, levels=3, per_image=500)
    assert info.words > 50 and not info.official
    return out


def test_vocabulary_loads_and_tracks_in_orbslam3(xyz_seq: Path, vocab: Path) -> None:
    pytest.importorskip("pyorbslam3", reason="the [slam] extra")
    from slimseg.slam.engines import run_orbslam3
    from slimseg.slam.orbslam3_config import write_settings

    seq = TumSequence(xyz_seq)
    settings = write_settings(xyz_seq.parent / "s.yaml", seq.camera, 320, 240)
    frames = [_frame(seq, i) for i in range(15)]
    run = run_orbslam3(frames, vocab, settings, realtime=False, log_path=xyz_seq.parent / "l")
    assert run.states[0] == "OK" and run.lost <= 3 and len(run.trajectory) >= 12
    assert "Vocabulary loaded" in (xyz_seq.parent / "l").read_text()


def _frame(seq: TumSequence, i: int):
    from slimseg.slam.engines import EngineFrame

    rgb, depth, t = seq.load(i)
    return EngineFrame(rgb, depth, t)


def test_bad_vocabulary_files_are_refused_before_orbslam3(tmp_path: Path) -> None:
    bad = tmp_path / "voc.txt"
    for text, match in (
        ("hello world\n", "DBoW2 header"),
        ("10 6 0 0\n0 1 1 2 3\n", r"voc.txt:2: expected 'parent is_leaf"),
        ("10 6 0 0\n", "no words"),
        ("10 6 0 0\n5 1 " + "0 " * 32 + "0.1\n", "parent < 1"),
    ):
        bad.write_text(text)
        with pytest.raises(SlimsegError, match=match):
            check_vocabulary(bad)
    with pytest.raises(SlimsegError, match="does not exist"):
        check_vocabulary(tmp_path / "ORBvoc.txt")


def test_slam_eval_bad_input(xyz_seq: Path, vocab: Path, tmp_path: Path, capsys) -> None:
    seq = tmp_path / "seq"
    shutil.copytree(xyz_seq, seq, ignore=shutil.ignore_patterns("background", "dynamic"))
    out = str(tmp_path / "out")
    base = ["slam-eval", "--sequence", str(seq), "--out", out]
    (seq / "groundtruth.txt").rename(seq / "gt.bak")
    assert main([*base, "--vocab", str(vocab)]) == 2
    assert "groundtruth.txt is missing" in capsys.readouterr().err
    (seq / "gt.bak").rename(seq / "groundtruth.txt")
    assert main(base) == 2
    assert "needs --vocab" in capsys.readouterr().err
    assert main([*base, "--vocab", str(tmp_path / "nope.txt")]) == 2
    assert "nope.txt does not exist" in capsys.readouterr().err
    masks = tmp_path / "masks"
    masks.mkdir()
    shutil.copy(next((xyz_seq / "dynamic").iterdir()), masks)
    assert main([*base, "--vocab", str(vocab), "--masks", str(masks)]) == 2
    assert "lacks 59 of 60 frames" in capsys.readouterr().err
    assert main([*base, "--modes", "raw,seg", "--vocab", str(vocab)]) == 2
    assert "need --model" in capsys.readouterr().err
    assert not (tmp_path / "out" / "results.csv").exists()


@pytest.mark.slow
def test_ground_truth_masks_lower_orbslam3_ate(xyz_seq: Path, vocab: Path, tmp_path, capsys):
    pytest.importorskip("pyorbslam3", reason="the [slam] extra")
    out = tmp_path / "eval"
    # medians of 3 runs: ORB-SLAM3's threads make runs spread; over 7 runs here raw was
    # 0.256-0.350 m, gt masks 0.069-0.188, gt instances 0.067-0.117, the still floor 0.102
    args = ["slam-eval", "--sequence", str(xyz_seq), "--vocab", str(vocab), "--modes", "raw,gt",
            "--runs", "3", "--out", str(out), "--json", "--quiet", "--no-realtime"]  # fmt: skip
    assert main(args) == 0
    rows = {r["condition"]: r for r in json.loads(capsys.readouterr().out)}
    raw, gt = rows["raw"]["ate_rmse"], rows["gt"]["ate_rmse"]
    assert gt < 0.7 * raw, (raw, gt)
    assert rows["still (floor)"]["ate_rmse"] < raw  # unmasked, walkers do worse than no motion
    md = (out / "results.md").read_text()
    assert "NON-OFFICIAL VOCABULARY" in md and "different dataset" in md
    assert (out / "trajectories" / "gt" / "run1.txt").is_file()
    assert (out / "trajectories.png").stat().st_size > 10_000
    # the masking logic on perfect detections (annotations.json) also lowers the ATE
    gti = ["slam-eval", "--sequence", str(xyz_seq), "--vocab", str(vocab), "--gt-instances",
           "--modes", "seg", "--runs", "3", "--out", str(tmp_path / "gti"), "--json", "--quiet",
           "--no-realtime"]  # fmt: skip
    assert main(gti) == 0
    seg = json.loads(capsys.readouterr().out)[0]
    # (a CI dry run read 0.157 m against raw 0.265: the same bound as the gt masks')
    assert seg["condition"] == "seg (gt instances)" and seg["ate_rmse"] < 0.7 * raw
    # the dense engine on the same frames: deterministic, no vocabulary
    assert main([*args[:5], "--engine", "dense", "--modes", "oracle", "--out",
                 str(tmp_path / "dense"), "--json", "--quiet"]) == 0  # fmt: skip
    dense = json.loads(capsys.readouterr().out)[0]
    assert dense["condition"] == "oracle" and dense["scored_runs"] == 1
    assert dense["ate_rmse"] < rows["still (floor)"]["ate_rmse"]


def test_core_imports_without_the_slam_extra(tmp_path: Path) -> None:
    """With pyorbslam3 and evo unimportable, the CLI loads and slam-eval says how to fix it."""
    code = (
        "import sys; sys.modules['pyorbslam3'] = None; sys.modules['evo'] = None\n"
        "from slimseg.cli.main import main\n"
        "assert not any(m.split('.')[0] in ('evo', 'pyorbslam3') and sys.modules[m] "
        "for m in list(sys.modules))\n"
        f"sys.exit(main(['slam-eval', '--sequence', {str(tmp_path)!r}, '--out', 'x']))\n"
    )
    (tmp_path / "rgb.txt").write_text("1.0 rgb/1.png\n")
    (tmp_path / "depth.txt").write_text("1.0 depth/1.png\n")
    (tmp_path / "groundtruth.txt").write_text("1.0 0 0 0 0 0 0 1\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "slimseg slam-eval: error: trajectory scoring needs the optional evo package: "
        "pip install 'slimseg[slam]' (GPL-3.0)"
    ]


def test_rows_mark_losses_and_runs_that_never_initialised() -> None:
    from slimseg.slam.condition_runs import ConditionResult, RunResult
    from slimseg.slam.conditions import Condition
    from slimseg.slam.engines import EngineRun
    from slimseg.slam.metrics import TrajectoryScore

    def run(i: int, lost: int, ate: float | None) -> RunResult:
        s = None if ate is None else TrajectoryScore(ate, 0.01, 0.0, 0.0, 0.0, 0.0, 150 - lost)
        err = "never initialised (0/150 frames tracked)" if ate is None else None
        return RunResult(i, 150, lost, 0, 30.0, None, s, err)

    res = ConditionResult(
        Condition("raw", "raw"), [run(1, 80, 0.3), run(2, 90, 0.1), run(3, 5, 0.2)]
    )
    s = res.summary()
    assert s["ate_rmse"] == 0.2 and (s["ate_min"], s["ate_max"]) == (0.1, 0.3)
    assert s["status"] == "lost 80/150 frames" and res.median_run().index == 3
    dead = ConditionResult(Condition("gt", "masked"), [run(1, 150, None)])
    assert dead.summary()["ate_rmse"] is None
    assert dead.status() == "not scored: never initialised (0/150 frames tracked)"
    states = ["NOT_INITIALIZED", "OK", "OK", "LOST", "LOST", "OK", "RECENTLY_LOST", "OK"]
    e = EngineRun(np.zeros((0, 8)), states)
    assert (e.lost, e.reinitialised) == (4, 2)


def test_slam_vocab_command(xyz_seq: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "v.txt"
    pattern = str(xyz_seq / "rgb" / "*.png")
    assert main(["slam", "vocab", "--images", pattern, "--out", str(out), "--k", "4",
                 "--levels", "2", "--max-images", "6", "--per-image", "300"]) == 0  # fmt: skip
    info = check_vocabulary(out)
    assert (info.k, info.levels) == (4, 2) and 4 < info.words <= 16
    assert "6 images" in capsys.readouterr().out
    assert out.read_text().splitlines()[0] == "4 2 0 0"
    assert main(["slam", "vocab", "--images", str(tmp_path / "*.jpg"), "--out", str(out)]) == 2
    assert "matched no file" in capsys.readouterr().err
