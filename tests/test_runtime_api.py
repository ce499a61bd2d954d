"""The public per-frame object (``slimseg.Masker``) and docs/runtime_api.md's loop: the example
block runs as written (ORB-SLAM3 included) and writes the masks ``slimseg dynamic`` writes."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from conftest import batchnorm_from, open_class_bias

import slimseg
from slimseg.cli.main import main
from slimseg.data.synth import generate
from slimseg.data.tum import TumSequence, mask_name
from slimseg.deploy.onnx_export import export_onnx
from slimseg.dynamic.masking_settings import PAPERS, PRESETS
from slimseg.errors import SlimsegError

ROOT = Path(__file__).resolve().parents[1]
NAMES = ["person", "chair", "car"]
MOBILITY = [1.0, 0.1, 0.3]
IMGSZ = 64


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runtime") / "data"
    generate(out, 1, 1, 64, 0, sequences=1, frames=24, seq_size=(320, 240), progress=False,
             preset="walking_xyz")  # fmt: skip
    return out / "sequences" / "seq_000"


@pytest.fixture(scope="module")
def model(sequence: Path) -> Path:
    """yolov8n-seg at 64 px with BatchNorm statistics of the sequence's frames and its class
    biases set so that few anchors score above the masking threshold, exported with slimseg's
    metadata."""
    torch.manual_seed(0)
    net = slimseg.build_model("yolov8n-seg", num_classes=len(NAMES))
    seq = TumSequence(sequence)
    frames = np.stack([cv2.resize(seq.load(i)[0], (IMGSZ, IMGSZ)) for i in range(0, 24, 4)])
    batch = torch.from_numpy(frames).permute(0, 3, 1, 2).float() / 255
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        batchnorm_from(net, batch)
        open_class_bias(net)
        with torch.no_grad():  # about 1 in 1000 anchor-class scores above 0.3
            scores = net(batch)[0][:, 4 : 4 + len(NAMES)]
            shift = torch.logit(scores.clamp(1e-6, 1 - 1e-6)).flatten().quantile(0.999)
            for branch in net.detect.cls:
                branch[-1].bias.sub_(float(shift) - float(torch.logit(torch.tensor(0.3))))
        out = sequence.parent.parent / "m.onnx"
        export_onnx(net, out, (IMGSZ, IMGSZ), NAMES, MOBILITY, simplify=False)
    return out


def _example() -> str:
    """The Python block docs/runtime_api.md marks as the runtime example."""
    text = (ROOT / "docs" / "runtime_api.md").read_text()
    found = re.search(r"<!-- runtime-example:[^>]*-->\s*```python\n(.*?)```", text, re.S)
    assert found, "docs/runtime_api.md lost its runtime-example block"
    return found.group(1)


def test_the_docs_loop_is_short() -> None:
    code = [ln for ln in _example().split('"""')[-1].splitlines() if ln.strip()]
    assert len(code) <= 30, len(code)


def test_the_docs_loop_runs_and_masks_as_slimseg_dynamic(
    sequence: Path, model: Path, tmp_path: Path, capsys
) -> None:
    pytest.importorskip("pyorbslam3", reason="the [slam] extra")
    from slimseg.slam.orbslam3_config import write_settings
    from slimseg.slam.vocab import build_vocabulary

    seq = TumSequence(sequence)
    vocab = build_vocabulary(sorted((sequence / "rgb").glob("*.png"))[::3], tmp_path / "voc.txt",
                             k=6, levels=3, per_image=500).path  # fmt: skip
    settings = write_settings(tmp_path / "s.yaml", seq.camera, 320, 240)
    script = tmp_path / "loop.py"
    script.write_text(_example())
    out = tmp_path / "loop"
    run = subprocess.run(
        [sys.executable, str(script), str(model), str(sequence), str(vocab), str(settings),
         str(out)], capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    lines = [ln for ln in run.stdout.splitlines() if re.match(r"^\d+\.\d{3} \w+ \d+ objects", ln)]
    assert len(lines) == len(seq) and sum(" OK " in ln for ln in lines) >= len(seq) // 2
    assert (out / "trajectory.txt").read_text().strip()

    argv = ["dynamic", "--model", str(model), "--sequence", str(sequence), "--track",
            "--threads", "1", "--out", str(tmp_path / "dyn"), "--quiet"]  # fmt: skip
    assert main(argv) == 0
    covered = []
    for i in range(len(seq)):
        name = mask_name(seq.load(i)[2])
        ours = cv2.imread(str(out / "masks" / name), cv2.IMREAD_GRAYSCALE)
        theirs = cv2.imread(str(tmp_path / "dyn" / "masks" / name), cv2.IMREAD_GRAYSCALE)
        assert np.array_equal(ours, theirs), name
        covered.append((ours > 0).mean())
    assert max(covered) > 0 and min(covered) < 0.9  # it masks something, not everything


def test_masker_settings_come_from_the_export(model: Path, sequence: Path) -> None:
    rgb, depth, stamp = TumSequence(sequence).load(0)
    with slimseg.Masker.from_onnx(model, threads=1) as m:
        c = m.config
        assert c.masking == PRESETS["slimseg"] and not c.track.on and c.track.rate.every_frame
        assert m.names == NAMES and np.allclose(m.mobility, MOBILITY)
        out = m.step(rgb, depth, stamp)
        assert out.mask.shape == (240, 320) and out.mask.dtype == np.uint8
        assert len(out.dynamic) == len(out.keypoints) > 0 and out.timing.latency > 0
    m = slimseg.Masker.from_onnx(model, threads=1, preset="papers", t_o=0.5, track="coast",
                                 rate="budget:30")  # fmt: skip
    c = m.config
    assert c.masking == PAPERS.with_values(t_o=0.5) and c.track.rate == slimseg.ModelRate.budget(30)
    assert c.track.on and c.floor == c.track.settings.low
    for bad, msg in (
        ({"preset": "fast"}, "no preset 'fast' (it has: papers, slimseg)"),
        ({"t_o": 2.0}, "t_o"),
        ({"rate": "often"}, "expected N, budget:MS or thread"),
        ({"rate": "3"}, "needs the track stage"),
        ({"track": "tight"}, "unknown track preset 'tight'"),
        ({"mode": "boxes"}, "mode 'boxes'"),
    ):
        with pytest.raises(SlimsegError, match=re.escape(msg)):
            slimseg.Masker.from_onnx(model, threads=1, **bad)


def test_masker_without_camera_says_so_once_or_refuses(model: Path, sequence: Path, caplog):
    """``slimseg.Masker`` built without ``camera`` cannot run the shipped preset's motion
    layers and stillness: it says so once in the log (by name), or refuses with ``strict``."""
    seq = TumSequence(sequence)
    with (
        caplog.at_level("WARNING", logger="slimseg"),
        slimseg.Masker.from_onnx(model, threads=1) as m,
    ):
        for i in range(3):
            m.step(*seq.load(i))
    said = [r.getMessage() for r in caplog.records if "cannot act" in r.getMessage()]
    assert len(said) == 1 and "no camera intrinsics" in said[0], said
    assert "motion_layer_px 100" in said[0] and "still_frames 20" in said[0]
    with pytest.raises(SlimsegError, match=r"still_frames 20 cannot act .*strict"):
        slimseg.Masker.from_onnx(model, threads=1, strict=True)
    caplog.clear()
    with (
        caplog.at_level("WARNING", logger="slimseg"),
        slimseg.Masker.from_onnx(model, threads=1, camera=seq.camera.pinhole, strict=True) as m,
    ):  # with the camera (and depth) every setting acts: nothing said
        m.step(*seq.load(0))
    assert not [r for r in caplog.records if "cannot act" in r.getMessage()]


def test_realtime_benchmark_runs_every_rate_through_the_object(model: Path, sequence: Path):
    """benchmarks/realtime_masks.py (the figures of docs/tracking.md section 6.6): one row per
    rate, shares of the per-frame recall, the emulated lag exactly as asked."""
    bench = ROOT / "benchmarks" / "realtime_masks.py"
    run = subprocess.run(
        [sys.executable, str(bench), "--sequence", str(sequence), "--model", str(model),
         "--rates", "per-frame,2,lag:2,lag:2-camera,thread", "--frames", "10", "--json"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    rows = {r["rate"]: r for r in json.loads(run.stdout)}
    assert list(rows) == ["per-frame", "2", "lag:2", "lag:2-camera", "thread"]
    assert rows["per-frame"]["recall_share_pct"] == 100 and rows["per-frame"]["x_first"] == 1
    assert rows["2"]["model_frames"] == 5 and rows["lag:2"]["lag_median"] == 2
    assert rows["lag:2"]["model_frames"] == rows["lag:2-camera"]["model_frames"] >= 4
    assert rows["thread"]["thread_model_ms"] > 0 and rows["thread"]["model_ms"] >= 0


@pytest.mark.parametrize("shape", [(1, 1, 3), (1, 5000, 3), (5000, 1, 3), (0, 128, 3)])
def test_a_degenerate_frame_is_masked_or_refused_in_one_line(model: Path, shape) -> None:
    """A 1x1 frame is masked (ORB finds nothing in it); one too thin to letterbox, or empty,
    is one SlimsegError line, never OpenCV's own error."""
    with slimseg.Masker.from_onnx(model, threads=1) as m:
        frame = np.zeros(shape, np.uint8)
        if shape == (1, 1, 3):
            assert m.step(frame).mask.shape == (1, 1)
        else:
            with pytest.raises(SlimsegError, match="letterbox") as e:
                m.step(frame)
            assert "\n" not in str(e.value)
