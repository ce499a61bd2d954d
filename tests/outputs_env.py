"""Shared fixtures of the issue-42 output and path tests (test_bad_inputs_outputs.py,
test_bad_inputs_paths.py): a tiny dataset, sequence, weights and export, and the helpers that
run the CLI in-process and snapshot a user's folder."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from slimseg.cli.main import main
from slimseg.data.synth import generate
from slimseg.data.synth.categories import MOBILITY, NAMES
from slimseg.deploy.onnx_export import export_onnx
from slimseg.models.checkpoint import WeightsInfo, save_weights
from slimseg.models.registry import build_model

IMGSZ = 64
USER = b"the user's own file, never to be lost"


@dataclass(frozen=True)
class Env:
    """A synthetic dataset (2 train + 1 val images, one 8-frame 96x64 sequence), random-init
    weights and their ONNX export, all at 64 px."""

    root: Path
    data: Path
    seq: Path
    weights: Path
    onnx: Path


def make_env(root: Path) -> Env:
    """The shared fixtures under ``root``."""
    generate(root / "d", 2, 1, IMGSZ, 0, sequences=1, frames=8, seq_size=(96, 64), progress=False)
    model = build_model("yolov8n-seg", num_classes=len(NAMES)).eval()
    info = WeightsInfo(model.spec, list(NAMES), list(MOBILITY), train_config={"imgsz": IMGSZ})
    weights = save_weights(root / "w.pt", model, info)
    onnx = root / "m.onnx"
    export_onnx(model, onnx, (IMGSZ, IMGSZ), list(NAMES), list(MOBILITY), simplify=False)
    return Env(root, root / "d" / "data.yaml", root / "d" / "sequences" / "seq_000", weights, onnx)


def run(argv: list[str], capfd: pytest.CaptureFixture[str], cwd: Path | None = None):
    """``(exit code, stderr lines, stdout)`` of ``slimseg argv`` run in-process."""
    capfd.readouterr()
    before = Path.cwd()
    if cwd is not None:
        os.chdir(cwd)
    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else 1
    finally:
        os.chdir(before)
    captured = capfd.readouterr()
    return code, [ln for ln in captured.err.splitlines() if ln.strip()], captured.out


def refused(argv: list[str], capfd: pytest.CaptureFixture[str], *names: str) -> str:
    """Assert one stderr line, exit 2, naming each of ``names``; returns the line."""
    code, err, _ = run(argv, capfd)
    assert code == 2 and len(err) == 1, (code, err)
    for name in names:
        assert name in err[0], err[0]
    return err[0]


def tree(folder: Path) -> dict[str, bytes | None]:
    """Every path under ``folder`` with its bytes (``None``: a folder)."""
    return {
        str(p.relative_to(folder)): (None if p.is_dir() else p.read_bytes())
        for p in sorted(folder.rglob("*"))
    }


def user_folder(path: Path, *names: str) -> dict[str, bytes | None]:
    """A user's folder holding ``names`` (``x/`` a subfolder with a file); its tree."""
    path.mkdir(parents=True, exist_ok=True)
    for name in names:
        if name.endswith("/"):
            (path / name).mkdir()
            (path / name / "keep.txt").write_bytes(USER)
        else:
            (path / name).write_bytes(USER)
    return tree(path)


def frames_folder(path: Path, names: list[str]) -> Path:
    """Images named ``names`` (PNG/JPEG by suffix), 120x160 blocks of random colours (ORB
    keypoints at the corners)."""
    path.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(len(names))
    for name in names:  # blocky noise: ORB finds keypoints in it
        blocks = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
        big = cv2.resize(blocks, (160, 120), interpolation=cv2.INTER_NEAREST)
        cv2.imwrite(str(path / name), big)
    return path


def _predict(env: Env, source: Path, out: Path, *extra: str) -> list[str]:
    return [
        "predict",
        "--model",
        str(env.onnx),
        "--source",
        str(source),
        "--out",
        str(out),
        "--quiet",
        *extra,
    ]


def _dyn(env: Env, seq: Path, out: Path) -> list[str]:
    return ["dynamic", "--gt-instances", "--sequence", str(seq), "--out", str(out), "--quiet"]


def _slam(seq: Path, out: Path) -> list[str]:
    return [
        "slam-eval",
        "--sequence",
        str(seq),
        "--out",
        str(out),
        "--engine",
        "dense",
        "--runs",
        "1",
        "--modes",
        "raw",
        "--quiet",
    ]


def _sweep(tmp: Path, env: Env, name: str = "tiny") -> Path:
    cfg = tmp / "sweep.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "name": name,
                "variants": ["yolov8n-seg"],
                "data": str(env.data),
                "train": {"recipe": "cpu-demo", "epochs": 1},
            }
        )
    )
    return cfg
