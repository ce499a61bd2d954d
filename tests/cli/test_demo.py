"""`slimseg demo`'s SLAM stage: the figure, the missing-extra path and the whole job shrunk."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from slimseg.cli import demo
from slimseg.cli.main import main
from slimseg.deploy.calibrated import read_model_metadata
from slimseg.models.checkpoint import WeightsInfo, save_weights
from slimseg.models.registry import build_model
from slimseg.slam import demo_run
from slimseg.slam.demo_plot import PlotCondition, plot_demo_slam

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
NAMES = ["person", "dog", "sports ball", "bottle", "chair", "tv"]


def _png(path: Path) -> np.ndarray:
    assert path.read_bytes()[:8] == PNG_MAGIC
    image = cv2.imread(str(path))
    assert image is not None and image.shape[0] > 300 and image.shape[1] > 600
    return image


def test_plot_of_hand_made_trajectories(tmp_path: Path) -> None:
    t = np.linspace(0, 2 * np.pi, 80)
    gt = np.stack([0.3 * np.sin(t), 0.05 * np.cos(2 * t), 0.2 * np.sin(0.5 * t)], 1)
    rng = np.random.default_rng(0)

    def runs(noise: float, n: int) -> list[np.ndarray]:
        return [gt + rng.normal(0, noise * (k + 1), gt.shape) for k in range(n)]

    conds = [
        PlotCondition("raw frames", runs(0.05, 3), [0.21, 0.18, 0.25], 3),
        PlotCondition("slimseg masks", runs(0.01, 2), [0.04, 0.03], 3),  # one run unscored
        PlotCondition("ground-truth masks", [], [], 3),  # nothing scored
    ]
    assert conds[0].median_index() == 0 and conds[1].median_index() == 1
    assert conds[2].median_index() is None
    out = plot_demo_slam(tmp_path / "sub" / "slam.png", gt, conds, "hand-made", floor=0.2)
    image = _png(out)
    assert image.std() > 10  # something was drawn
    assert [p.name for p in out.parent.iterdir()] == ["slam.png"]  # no temporary left


def test_missing_slam_extra_is_named(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pyorbslam3", None)  # an import of it now fails
    assert demo_run.slam_extra_missing() == ["pyorbslam3"]
    monkeypatch.setitem(sys.modules, "evo", None)
    assert demo_run.slam_extra_missing() == ["pyorbslam3", "evo"]


@pytest.mark.slow
def test_missing_slam_extra_is_one_line_and_the_export_still_happens(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "pyorbslam3", None)
    model = build_model("yolov8n-seg-gs-rep", num_classes=len(NAMES)).eval()
    info = WeightsInfo(model.spec, NAMES, [1.0, 0.75, 0.75, 0.5, 0.25, 0.0])
    weights = save_weights(tmp_path / "best.pt", model, info)
    args = argparse.Namespace(model="yolov8n-seg-gs-rep", seed=0)
    metrics: dict = {"box": {}}
    summary = demo._slam_stage(args, weights, 64, tmp_path, metrics)
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith("[5/6] exporting")
    assert (tmp_path / "export" / "yolov8n-seg-gs-rep.onnx").is_file()
    skipped = [line for line in printed if "pip install 'slimseg[slam]'" in line]
    assert len(skipped) == 1 and skipped[0].startswith("[6/6]") and "pyorbslam3" in skipped[0]
    assert summary.result is None and "slam" not in metrics
    assert not (tmp_path / "slam").exists()


@pytest.mark.slow
def test_demo_with_the_slam_stage_small(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    """The whole `make demo` shrunk: 16 + 16 sequence-world frames at 320x240, 1 epoch at
    64 px, then 30 frames at 320x240 tracked twice per condition."""
    pytest.importorskip("pyorbslam3", reason="the [slam] extra")
    pytest.importorskip("evo", reason="the [slam] extra")
    out = tmp_path / "demo"
    argv = ["demo", "--out", str(out), "--epochs", "1", "--seq-train", "1", "--seq-val", "1",
            "--imgsz", "64", "--quiet", "--slam-frames", "30", "--slam-size", "320", "240",
            "--slam-runs", "2", "--calibration-budget", "20"]  # fmt: skip
    assert main(argv) == 0
    printed = capsys.readouterr().out
    steps = [line.split("]")[0] + "]" for line in printed.splitlines() if line[:1] == "["]
    assert steps == [f"[{k}/6]" for k in range(1, 7)]
    _png(out / "slam.png")
    metrics = json.loads((out / "metrics.json").read_text())
    assert {"box", "mask", "per_class", "slam"} <= set(metrics)
    slam = metrics["slam"]
    assert set(slam["conditions"]) == {"raw", "slimseg", "gt_masks"}
    assert slam["sequence"]["seed"] == 1 and slam["sequence"]["frames"] == 30
    for key, row in slam["conditions"].items():
        assert row["runs"] == 2 and len(row["ate_runs_m"]) == 2, key
        ate = row["ate_median_m"]
        assert ate is not None and math.isfinite(ate) and ate > 0, (key, row)
        assert row["ate_min_m"] <= ate <= row["ate_max_m"]
    assert math.isfinite(slam["still_camera_ate_m"])
    for rel in ("slam/results.md", "slam/runs.csv", "export/yolov8n-seg-gs-rep.onnx",
                "export/yolov8n-seg-gs-rep_calibration/report.png"):  # fmt: skip
        assert (out / rel).is_file(), rel
    calibrated = read_model_metadata(out / "export" / "yolov8n-seg-gs-rep_calibrated.onnx")
    assert calibrated["slam_masking"]["preset"] == "calibrated"
    assert slam["masking"].startswith("fusion mode, calibrated preset")
    last = printed.strip().splitlines()[-1]
    assert last.startswith("mask mAP50-95 ") and "ATE raw " in last, last
    assert "→ slimseg " in last and "→ ground-truth masks " in last and "2 ORB-SLAM3 runs" in last
    assert "a camera that never moves " in last


def test_result_line_says_when_the_masks_did_not_help() -> None:
    def row(m: tuple) -> dict:
        return {"ate_median_m": m[0], "ate_min_m": m[1], "ate_max_m": m[2]}

    def table(raw: tuple, ours: tuple, floor: float | None = 0.099) -> dict:
        conds = {"raw": row(raw), "slimseg": row(ours), "gt_masks": row((0.017,) * 3)}
        seq = {"preset": "walking_xyz", "seed": 1, "frames": 100}
        return {"conditions": conds, "runs_per_condition": 5, "sequence": seq,
                "still_camera_ate_m": floor}  # fmt: skip

    line = demo._result(table((0.24, 0.2, 0.3), (0.03, 0.02, 0.04)))
    assert line == ("ATE raw 0.240 m → slimseg 0.030 m → ground-truth masks 0.017 m; a camera "
                    "that never moves 0.099 m (median of 5 ORB-SLAM3 runs each, walking_xyz "
                    "seed 1, 100 frames)")  # fmt: skip
    assert "never moves" not in demo._result(table((0.24, 0.2, 0.3), (0.03, 0.02, 0.04), None))
    assert "did not lower" in demo._result(table((0.1, 0.1, 0.1), (0.2, 0.1, 0.3)))
    # the demo line: 0.295 → 0.102 with a still camera at 0.099
    failed = demo._result(table((0.295, 0.28, 0.3), (0.102, 0.09, 0.11)))
    assert "above 0.5× the still camera's" in failed and "overlap" not in failed
    assert "overlap" in demo._result(table((0.2, 0.1, 0.3), (0.15, 0.1, 0.2), 0.5))
    assert "slimseg not scored" in demo._result(table((0.2, 0.1, 0.3), (None, None, None)))


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--slam-frames", "5"], "--slam-frames 5: need at least 10"),
        (["--slam-runs", "0"], "--slam-runs 0: need at least 1"),
        (["--vocab", "nope.txt"], "--vocab nope.txt does not exist"),
    ],
)
def test_bad_slam_options_fail_before_training(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], needle: str
) -> None:
    assert main(["demo", "--out", str(tmp_path / "demo"), *extra]) == 2
    assert needle in capsys.readouterr().err
    assert not (tmp_path / "demo").exists()  # nothing generated, nothing trained
