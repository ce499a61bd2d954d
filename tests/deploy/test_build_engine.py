"""``export/build_engine.sh`` without TensorRT: a stand-in ``trtexec`` records its arguments.
The profile of a ``--dynamic`` export is possible at every size (min <= opt <= max), ``--help``
answers without TensorRT, and the file checks come before trtexec is looked for."""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "export" / "build_engine.sh"
NO_TRT_PATH = os.pathsep.join(["/usr/bin", "/bin"])  # bash and python3, no trtexec


def _model(root: Path, imgsz: list[int], **meta) -> Path:
    (root / "m.onnx").write_bytes(b"")
    sidecar = {"imgsz": imgsz, "dynamic_shapes": True, "precision": "fp32", **meta}
    (root / "m.json").write_text(json.dumps(sidecar))
    return root / "m.onnx"


def _run(args: list[str], path: str, **env) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPT), *args], env={**os.environ, "PATH": path, **env},
                          capture_output=True, text=True)  # fmt: skip


@pytest.fixture
def stub(tmp_path: Path) -> tuple[str, Path]:
    """PATH with a trtexec that prints TensorRT 10.3 and writes its arguments to args.txt."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    record = tmp_path / "args.txt"
    (bin_dir / "trtexec").write_text(
        '#!/usr/bin/env bash\nif [ "$1" = --help ]; then echo "TensorRT v100300"; exit 0; fi\n'
        f'echo "$@" > {record}\n'
    )
    (bin_dir / "trtexec").chmod(0o755)
    return f"{bin_dir}{os.pathsep}{os.environ['PATH']}", record


# (imgsz, MAX_BATCH): below, at and above 320 px, square and not
CASES = [([64, 64], "4"), ([256, 320], "1"), ([320, 256], "4"), ([320, 320], "4"),
         ([736, 1280], "2")]  # fmt: skip


def _shape(args: str, key: str) -> list[int]:
    found = re.search(rf"--{key}Shapes=images:(\d+)x3x(\d+)x(\d+)", args)
    assert found, args
    return [int(v) for v in found.groups()]


def test_dynamic_profiles_are_possible_at_every_size(tmp_path, stub) -> None:
    path, record = stub
    for imgsz, max_batch in CASES:
        onnx = _model(tmp_path, imgsz)
        done = _run([str(onnx), str(tmp_path / "m.engine"), max_batch], path)
        assert done.returncode == 0, done.stderr
        args = record.read_text()
        lo, opt, hi = (_shape(args, k) for k in ("min", "opt", "max"))
        assert opt == [1, *imgsz] and hi == [int(max_batch), *imgsz]
        assert all(a <= b <= c for a, b, c in zip(lo, opt, hi, strict=True)), (imgsz, args)
        assert lo[1] == lo[2] == min(320, *imgsz)
    onnx = _model(tmp_path, [640, 640])
    assert _run([str(onnx)], path, MIN_SIZE="256").returncode == 0
    assert _shape(record.read_text(), "min") == [1, 256, 256]
    done = _run([str(_model(tmp_path, [256, 256]))], path, MIN_SIZE="320")
    assert done.returncode == 2 and "MIN_SIZE 320: larger than the export's 256x256" in done.stderr
    done = _run([str(onnx)], path, MIN_SIZE="100")
    assert done.returncode == 2 and "MIN_SIZE 100: expected a multiple of 32" in done.stderr


def test_help_and_usage_without_tensorrt(tmp_path) -> None:
    done = _run(["--help"], NO_TRT_PATH)
    assert done.returncode == 0, done.stderr
    assert "Build a TensorRT engine" in done.stdout and "min <= opt <= max" in done.stdout
    done = _run([], NO_TRT_PATH)
    assert done.returncode == 2 and done.stderr.startswith("usage: build_engine.sh MODEL.onnx")
    done = _run([str(tmp_path / "none.onnx")], NO_TRT_PATH)
    assert done.returncode == 2 and "none.onnx: file not found" in done.stderr
    done = _run([str(_model(tmp_path, [320, 320])), "e.engine", "0"], NO_TRT_PATH)
    assert done.returncode == 2 and "MAX_BATCH 0" in done.stderr


def test_file_checks_come_before_trtexec(tmp_path) -> None:
    """Without TensorRT the script still says that an onnxruntime-target INT8 file is the
    wrong file, and that a file without sidecar was not made by slimseg export; a good file
    gets "trtexec not found"."""
    meta = {"precision": "int8", "int8": {"target": "onnxruntime"}}
    done = _run([str(_model(tmp_path, [320, 320], **meta))], NO_TRT_PATH)
    assert done.returncode == 2 and "--int8-target tensorrt" in done.stderr, done.stderr
    (tmp_path / "m.json").unlink()
    done = _run([str(tmp_path / "m.onnx")], NO_TRT_PATH)
    assert done.returncode == 2 and "m.json missing" in done.stderr
    (tmp_path / "m.json").write_text("{}")
    done = _run([str(tmp_path / "m.onnx")], NO_TRT_PATH)
    assert done.returncode == 2 and "not a slimseg sidecar" in done.stderr
    done = _run([str(_model(tmp_path, [320, 320]))], NO_TRT_PATH)
    assert done.returncode == 2 and "trtexec not found" in done.stderr
