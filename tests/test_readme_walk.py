"""The README's path, command after command, through the real CLI entry point on tiny sizes.

data synth (with sequences) → data check → train → val → export → predict → dynamic →
slam vocab → slam-eval: each command reads what the one before wrote, with the README's flags
(only the sizes shrunk), so a writer/reader mismatch between two commands (data.yaml's
``sequences:`` once stopped ``slimseg train``) fails here. Also: data.yaml's regenerate comment
reproduces the dataset byte for byte, and a sequences-only set is refused by ``train`` in one
line. The slam-eval step needs the ``[slam]`` extra (ORB-SLAM3) and is skipped without it.
"""

from __future__ import annotations

import json
import shlex
from pathlib import Path

import pytest

from slimseg.cli.main import main
from slimseg.data.config import load_data_config
from slimseg.data.tum import TumSequence

DATA = "data/seq/data.yaml"
# the README's sequence example, shrunk; 320x240 frames so that ORB-SLAM3 initialises
SYNTH = ["--out", "data/seq", "--train", "4", "--val", "2", "--imgsz", "64", "--sequences", "1"]
SYNTH += ["--frames", "12", "--seq-size", "320", "240", "--preset", "walking_xyz", "--quiet"]
# the README's train example (cpu-demo recipe, --out), one tiny epoch
TRAIN = ["--config", "cpu-demo", "--epochs", "1", "--imgsz", "64", "--batch", "2"]
TRAIN += ["--out", "runs/x", "--quiet"]


def _run(capsys: pytest.CaptureFixture[str], *argv: str, rc: int = 0) -> str:
    """``slimseg ARGV`` in this process; asserts the exit code, returns what it printed."""
    code = main(list(argv))
    out, err = capsys.readouterr()
    assert code == rc, (argv, out[-2000:], err[-2000:])
    return out if rc == 0 else err


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in root.rglob("*") if p.is_file()}


@pytest.mark.slow
def test_readme_commands_in_order(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    _run(capsys, "data", "synth", *SYNTH)
    cfg = load_data_config(DATA)  # the reader takes everything the writer wrote
    seq = cfg.sequences["seq_000"]
    assert list(cfg.sequences) == ["seq_000"] and cfg.train is not None and cfg.val is not None

    # the comment in data.yaml is the command that writes the same dataset
    comment = Path(DATA).read_text().splitlines()[1]
    argv = shlex.split(comment.removeprefix("# ").replace("<dir>", "data/regen"))
    assert argv[:3] == ["slimseg", "data", "synth"] and "--preset" in argv
    _run(capsys, *argv[1:], "--quiet")
    assert _files(Path("data/regen")) == _files(Path("data/seq"))

    assert "OK: 0 errors" in _run(capsys, "data", "check", DATA)
    _run(capsys, "train", "--model", "yolov8n-seg", "--data", DATA, *TRAIN)
    best = "runs/x/weights/best.pt"
    metrics = json.loads(_run(capsys, "val", "--weights", best, "--data", DATA, "--json"))
    assert {"box", "mask", "per_class"} <= set(metrics)
    _run(capsys, "export", "--weights", best, "--imgsz", "64", "--out", "export/m.onnx", "--quiet")
    _run(capsys, "predict", "--model", "export/m.onnx", "--source", str(seq / "rgb"),
         "--out", "runs/predict")  # fmt: skip
    frames = TumSequence(seq)
    assert len(list(Path("runs/predict").glob("*_mask.png"))) == len(frames)

    printed = _run(capsys, "dynamic", "--model", "export/m.onnx", "--sequence", str(seq),
                   "--out", "runs/dyn", "--mode", "fusion", "--quiet")  # fmt: skip
    cam = frames.camera
    intrinsics = f"intrinsics: fx {cam.fx}, fy {cam.fy}, cx {cam.cx}, cy {cam.cy} from "
    assert printed.startswith(intrinsics + str(seq / "camera.yaml")), printed[:300]
    assert len(list(Path("runs/dyn/masks").glob("*.png"))) == len(frames)

    # a sequences-only set: written, then refused by train in one line naming the file
    _run(capsys, "data", "synth", "--out", "data/only", "--train", "0", "--val", "0",
         "--sequences", "1", "--frames", "2", "--seq-size", "96", "64", "--quiet")  # fmt: skip
    only = load_data_config("data/only/data.yaml")
    assert only.train is None and only.val is None and list(only.sequences) == ["seq_000"]
    err = _run(capsys, "train", "--model", "yolov8n-seg", "--data", "data/only/data.yaml", rc=2)
    assert len(err.strip().splitlines()) == 1
    assert "data/only/data.yaml: no 'train' split" in err and not Path("runs/yolov8n-seg").exists()

    pytest.importorskip("pyorbslam3", reason="slam-eval needs the [slam] extra")
    pytest.importorskip("evo", reason="slam-eval needs the [slam] extra")
    _run(capsys, "slam", "vocab", "--images", f"{seq}/rgb/*.png", "--out", "voc.txt",
         "--k", "6", "--levels", "3")  # fmt: skip
    printed = _run(capsys, "slam-eval", "--sequence", str(seq), "--vocab", "voc.txt",
                   "--model", "export/m.onnx", "--modes", "raw,gt,fusion", "--runs", "1",
                   "--out", "runs/slam", "--no-realtime", "--quiet")  # fmt: skip
    assert intrinsics in printed and Path("runs/slam/results.csv").is_file()
