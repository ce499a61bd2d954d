"""`slimseg dynamic` on a generated TUM sequence: masks named by timestamp, CSV, scores."""

from __future__ import annotations

from pathlib import Path

import cv2
import pytest

from slimseg.cli.main import main
from slimseg.data.synth import generate
from slimseg.deploy.checkpoint import WeightsInfo, save_weights
from slimseg.dynamic.tum import TumSequence, mask_name
from slimseg.models.registry import build_model


@pytest.mark.slow
def test_dynamic_command_on_a_synthetic_sequence(tmp_path: Path, capsys) -> None:
    generate(
        tmp_path / "d", 1, 1, 64, 0, sequences=1, frames=4, seq_size=(160, 128), progress=False
    )
    seq = tmp_path / "d" / "sequences" / "seq_000"
    model = build_model("yolov8n-seg", num_classes=6).eval()
    names = ["person", "dog", "sports ball", "bottle", "chair", "tv"]
    info = WeightsInfo(
        model.spec, names, [1.0, 0.75, 0.75, 0.5, 0.25, 0.0], train_config={"imgsz": 128}
    )
    weights = save_weights(tmp_path / "w.pt", model, info)
    out = tmp_path / "out"
    argv = ["dynamic", "--model", str(weights), "--sequence", str(seq), "--out", str(out)]
    assert main([*argv, "--conf", "0.0", "--min-static", "5", "--quiet"]) == 0
    frames = TumSequence(seq)
    for i in range(len(frames)):
        _, _, stamp = frames.load(i)
        mask = cv2.imread(str(out / "masks" / mask_name(stamp)), cv2.IMREAD_GRAYSCALE)
        assert mask.shape == (128, 160)
    assert len((out / "frames.csv").read_text().splitlines()) == len(frames) + 1
    assert (out / "overlay.png").is_file()
    printed = capsys.readouterr().out
    assert "precision %" in printed and "box+depth-ransac" in printed
