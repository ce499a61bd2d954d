"""The `slimseg` entry point as a user runs it."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from conftest import measured

from slimseg.cli.main import main


@pytest.fixture
def measured_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """`slimseg info` measures through tests/conftest.py's session cache: a variant that
    tests/models/test_complexity.py measured (the same build, the same 640 px) is not counted
    again (on a miss the command's own call runs, and the numbers are asserted either way)."""
    from slimseg.cli import info_models

    monkeypatch.setattr(info_models, "measure", measured)


@pytest.mark.usefixtures("measured_once")
def test_info_single_model_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", "--model", "yolov8n-seg", "--nc", "20", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["model"] == "yolov8n-seg"
    assert data["params"] == 3_267_516 and data["fused_params"] == 3_261_964
    assert data["gflops"] == pytest.approx(11.362, abs=5e-4)
    assert sum(data["components"].values()) == data["params"]


@pytest.mark.usefixtures("measured_once")
def test_info_fused_build(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", "--model", "yolov8s-seg-gs-rep", "--nc", "20", "--fused", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["params"] == data["fused_params"] == 9_073_255


@pytest.mark.usefixtures("measured_once")
def test_info_table_for_one_model(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", "--model", "yolov8s-seg-gs", "--nc", "20"]) == 0
    out = capsys.readouterr().out
    assert "10,015,948" in out and "10,938,700" in out and "neck" in out


@pytest.mark.slow
@pytest.mark.usefixtures("measured_once")
def test_info_all_compares_with_paper(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", "--model", "all", "--nc", "20"]) == 0
    out = capsys.readouterr().out
    assert "Table II" in out
    for name in ("yolov8s-seg-gs-rep", "darknet19-yolov3", "yolov8n"):
        assert name in out


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["info", "--model", "yolov8q"], "unknown model 'yolov8q'; valid:"),
        (["info", "--model", "yolov8n-seg", "--imgsz", "100"], "not a multiple of 32"),
    ],
)
def test_errors_are_one_line_and_nonzero(argv: list[str], needle: str) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "slimseg", *argv], capture_output=True, text=True, check=False
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in proc.stderr


@pytest.mark.slow
def test_demo_end_to_end_small(tmp_path) -> None:
    """The README's main job, shrunk (one training and one validation world, still images
    mixed in): 1 epoch is not a multiple of val_every (3), so the final weights must still be
    validated and written."""
    out = tmp_path / "demo"
    argv = ["demo", "--out", str(out), "--epochs", "1", "--train-images", "8", "--no-slam",
            "--seq-train", "1", "--seq-val", "1", "--slam-size", "320", "240"]  # fmt: skip
    assert main([*argv, "--val-images", "4", "--imgsz", "96", "--quiet"]) == 0
    for rel in ("results.png", "predictions.png", "metrics.json", "train/weights/best.pt"):
        assert (out / rel).is_file(), rel
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics) >= {"box", "mask", "per_class", "speed_ms"}
    assert "slam" not in metrics and not (out / "export").exists()  # --no-slam
