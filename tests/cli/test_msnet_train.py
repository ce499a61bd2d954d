"""CLI for MSNET (train, val, predict) and ``val --semantic`` for a YOLO segmenter."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import pytest
import torch
import yaml

from slimseg.cli.main import main
from slimseg.data.synth import generate
from slimseg.errors import SlimsegError
from slimseg.models.checkpoint import load_weights

RECIPE = {
    "epochs": 2,
    "batch": 4,
    "imgsz": 96,
    "optimizer": "adamw",
    "lr0": 0.002,
    "warmup_epochs": 0.0,
    "close_mosaic": 0,
    "workers": 0,
    "ema_decay": 0.9,
    "val_every": 1,
}


@pytest.fixture(scope="module")
def setup(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("msnet")
    data = generate(root / "ds", 8, 4, 96, seed=3, progress=False).data_yaml
    recipe = root / "recipe.yaml"
    recipe.write_text(yaml.safe_dump(RECIPE))
    return data, recipe


@pytest.mark.slow
def test_train_val_predict_cli(
    setup: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    data, recipe = setup
    out = tmp_path / "run"
    argv = ["train", "--model", "msnet-t", "--data", str(data), "--config", str(recipe)]
    assert main([*argv, "--out", str(out), "--quiet", "--accelerator", "cpu"]) == 0
    printed = capsys.readouterr().out
    assert "mIoU" in printed and "background" in printed
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 and {"val/miou", "val/mpa"} <= set(rows[0])
    assert all(0.0 <= float(r["val/miou"]) <= 1.0 for r in rows)
    _, info = load_weights(out / "weights" / "best.pt")
    assert info.spec.family == "msnet" and "miou" in info.metrics
    best = max(float(r["val/miou"]) for r in rows)
    assert info.metrics["miou"] == pytest.approx(best, abs=1e-6)  # best.pt = highest mIoU

    weights = str(out / "weights" / "best.pt")
    assert main(["val", "--weights", weights, "--data", str(data), "--json", "--workers", "0"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert {"miou", "mpa", "per_class", "speed_ms"} <= set(result)
    assert [c["name"] for c in result["per_class"]][:2] == ["background", info.names[0]]
    assert result["miou"] == pytest.approx(info.metrics["miou"], abs=1e-6)

    image = next((data.parent / "val" / "images").iterdir())
    pred_dir = tmp_path / "pred"
    assert (
        main(["predict", "--model", weights, "--source", str(image), "--out", str(pred_dir)]) == 0
    )
    classes = cv2.imread(str(pred_dir / f"{image.stem}_classes.png"), cv2.IMREAD_UNCHANGED)
    assert classes.shape == (96, 96) and classes.max() <= len(info.names)
    assert (pred_dir / f"{image.stem}_overlay.png").is_file()
    assert "class_pixels" in json.loads((pred_dir / f"{image.stem}.json").read_text())


@pytest.mark.slow
def test_yolo_segmenter_scored_with_semantic_metrics(
    setup: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    data, recipe = setup
    out = tmp_path / "yolo"
    argv = ["train", "--model", "yolov8n-seg", "--data", str(data), "--config", str(recipe)]
    assert main([*argv, "--epochs", "1", "--out", str(out), "--quiet", "--accelerator", "cpu"]) == 0
    capsys.readouterr()
    weights = str(out / "weights" / "best.pt")
    argv = ["val", "--weights", weights, "--data", str(data), "--workers", "0", "--semantic"]
    assert main([*argv, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert len(result["per_class"]) == 7 and 0.0 <= result["miou"] <= 1.0
    assert result["pixels"] == 4 * 96 * 96
    assert main(argv) == 0
    assert "as a class map" in capsys.readouterr().out


def test_semantic_val_of_a_detector_is_a_clear_error() -> None:
    from slimseg.eval.validation import semantic_batch
    from slimseg.models.registry import build_model

    model = build_model("yolov8n", num_classes=6).eval()
    with pytest.raises(SlimsegError, match="not a segmenter"):
        semantic_batch(model, {"images": torch.zeros(1, 3, 64, 64, dtype=torch.uint8)})
