"""`slimseg dynamic` on a generated TUM sequence: masks named by timestamp, CSV, scores."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from slimseg.cli.main import main
from slimseg.data.synth import generate
from slimseg.data.tum import TumSequence, mask_name
from slimseg.models.checkpoint import WeightsInfo, save_weights
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
    assert main([*argv, "--set", "conf=0.0", "min_static=5", "--quiet"]) == 0
    frames = TumSequence(seq)
    for i in range(len(frames)):
        _, _, stamp = frames.load(i)
        mask = cv2.imread(str(out / "masks" / mask_name(stamp)), cv2.IMREAD_GRAYSCALE)
        assert mask.shape == (128, 160)
    rows = (out / "frames.csv").read_text().splitlines()
    assert len(rows) == len(frames) + 1
    assert {"support", "dropped", "dropped_confident", "still"} <= set(rows[0].split(","))
    assert (out / "overlay.png").is_file()
    printed = capsys.readouterr().out
    assert "precision %" in printed and "box+depth-ransac" in printed


@pytest.fixture(scope="module")
def small_sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("synth")
    generate(root, 1, 1, 64, 0, sequences=1, frames=6, seq_size=(160, 128), progress=False)
    return root / "sequences" / "seq_000"


def test_epipolar_mode_and_restore_with_gt_instances(
    small_sequence: Path, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "out"
    argv = ["dynamic", "--gt-instances", "--sequence", str(small_sequence), "--out", str(out)]
    assert main([*argv, "--mode", "semantic+epipolar", "--restore", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "semantic+epipolar" in printed and "fusion+epipolar" in printed
    assert "epipolar check of ground-truth instances" in printed
    assert "PatchMatch (ours)" in printed and "cv2.inpaint Telea" in printed
    rows = (out / "restoration.csv").read_text().splitlines()
    assert rows[0].startswith("method,PSNR dB,SSIM") and len(rows) == 5
    frames = TumSequence(small_sequence)
    for i in range(len(frames)):
        rgb, depth, stamp = frames.load(i)
        name = mask_name(stamp)
        restored = cv2.imread(str(out / "restored" / "rgb" / name))
        raw = cv2.imread(str(out / "restored" / "depth" / name), cv2.IMREAD_UNCHANGED)
        assert restored.shape == (128, 160, 3) and raw.dtype == np.uint16
        gt = cv2.imread(str(small_sequence / "dynamic" / name), cv2.IMREAD_GRAYSCALE) > 0
        keep = ~cv2.dilate(gt.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
        assert np.array_equal(restored[keep], cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)[keep])
        assert np.allclose(raw[keep] / 5000.0, depth[keep], atol=1e-3)
        if gt.any():  # the walker is gone: the fill is not its colour or depth
            assert np.abs(raw[gt] / 5000.0 - depth[gt]).mean() > 0.05
    assert not list((out / "restored" / "rgb").glob(".*"))  # no temp files left


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--model", "x.onnx", "--gt-instances"], "exactly one of --model"),
        ([], "exactly one of --model"),
    ],
)
def test_dynamic_command_rejects_bad_arguments(
    small_sequence: Path, tmp_path: Path, capsys, extra: list[str], message: str
) -> None:
    argv = ["dynamic", "--sequence", str(small_sequence), "--out", str(tmp_path), *extra]
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_restore_gt_masks_need_a_dynamic_folder(tmp_path: Path, capsys) -> None:
    generate(tmp_path / "d", 1, 1, 64, 0, sequences=1, frames=2, seq_size=(96, 64), progress=False)
    seq = tmp_path / "d" / "sequences" / "seq_000"
    for f in (seq / "dynamic").iterdir():
        f.unlink()
    (seq / "dynamic").rmdir()
    argv = ["dynamic", "--gt-instances", "--sequence", str(seq), "--out", str(tmp_path / "o")]
    assert main([*argv, "--restore", "--quiet"]) == 2
    assert "--restore-mask gt needs ground-truth masks" in capsys.readouterr().err


def test_restore_rejects_masks_of_the_wrong_size(small_sequence: Path, tmp_path: Path) -> None:
    from slimseg.errors import SlimsegError
    from slimseg.sequence.restore_run import restore_sequence

    with pytest.raises(SlimsegError, match=r"is \(80, 64\) \(w, h\) but the frame is \(160, 128\)"):
        restore_sequence(
            small_sequence, lambda i, t: np.zeros((64, 80), np.uint8), tmp_path, progress=False
        )


def test_the_rules_report_what_they_gave_up(small_sequence: Path, tmp_path: Path, capsys) -> None:
    """Support that can never suffice: Eq. 1 gives up every frame with a walker, the degrading
    rule never drops a ground-truth instance (score 1 >= keep_score)."""
    base = ["dynamic", "--gt-instances", "--sequence", str(small_sequence), "--quiet",
            "--set", "min_static=100000", "--mode", "seg"]  # fmt: skip
    assert main([*base, "--out", str(tmp_path / "eq1"), "--set", "rule=eq1"]) == 0
    eq1 = capsys.readouterr().out
    assert main([*base, "--out", str(tmp_path / "deg")]) == 0
    deg = capsys.readouterr().out
    gave_up = int(eq1.split("the frame given up in ")[1].split()[0])
    assert gave_up > 0 and "masking rule (eq1)" in eq1
    assert f"left out in {gave_up} frames" in eq1  # score-1 walkers among what it gave up
    assert "masking rule (degrade): 0 candidate masks left out" in deg
    assert "the frame given up in 0" in deg


def test_no_depth_masks_from_colour_alone_and_says_so(
    small_sequence: Path, tmp_path: Path, capsys
) -> None:
    """``--no-depth``: the chain sees no depth (an RGB-only camera): one line says the depth cut
    cannot act and Eq. 4 falls back to the papers' t_o; with depth that line is absent."""
    base = ["dynamic", "--gt-instances", "--sequence", str(small_sequence), "--quiet"]
    assert main([*base, "--out", str(tmp_path / "d"), "--mode", "fusion"]) == 0
    assert "no depth image" not in capsys.readouterr().out
    assert main([*base, "--out", str(tmp_path / "n"), "--mode", "fusion", "--no-depth"]) == 0
    lines = [x for x in capsys.readouterr().out.splitlines() if "no depth image" in x]
    assert len(lines) == 1 and "at most 0.25" in lines[0]
    names = sorted(p.name for p in (tmp_path / "d" / "masks").glob("*.png"))
    assert names == sorted(p.name for p in (tmp_path / "n" / "masks").glob("*.png"))
