"""The C++ multi-frame chain beside ``slimseg dynamic``'s: mask pixel agreement and cost per frame.

    python benchmarks/cpp_chain.py --sequence SEQ --model M.onnx --example build/cpp/slimseg_masks \
        --work runs/cpp_chain [--json]

Writes ``slimseg predict --dump-raw --dump-depth`` dumps of the TUM-layout sequence once
(``WORK/dumps``: the chain's ORB keypoints, descriptors and corners, the depth and the camera;
an export older than the multi-frame settings gets the shipped preset's values in the dumps'
metadata), then, in one run and on one thread each (the predictor, OpenCV and BLAS at 1):
(a) the Python chain (``run_sequence``, fusion, the ``slimseg`` preset; its stages after the
model and ORB from ``FrameTiming.stages``: objects, stillness, mobility, layers, rules) writing
``WORK/dyn/masks``; (b) the example on the dumps (``FrameChain::step``'s own clock) writing
``WORK/cpp``. Prints the per-frame pixel agreement of the two mask sets and the ms per frame of
each (docs/cpp_consumer.md, "Measured").
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
from pathlib import Path

import cv2
import numpy as np

from slimseg.cli.main import main as cli
from slimseg.deploy.predictor import Predictor
from slimseg.dynamic.chain_config import ChainConfig
from slimseg.dynamic.knobs import preset_values
from slimseg.dynamic.masking_settings import PRESETS
from slimseg.sequence.sequence_run import run_sequence

MULTI_FRAME = ("motion_odds", "motion_layer_px", "still_frames")
PYTHON_STAGES = ("objects", "stillness", "mobility", "layers", "rules")


def dump(sequence: Path, model: str, dumps: Path) -> None:
    """``predict --dump-raw --dump-depth`` into ``dumps`` (once), the metadata given the shipped
    preset's multi-frame settings where the export lacks them."""
    if dumps.exists():
        return
    argv = ["predict", "--model", model, "--source", str(sequence / "rgb"), "--quiet",
            "--threads", "1", "--dump-depth", str(sequence), "--out", str(dumps.parent / "pred"),
            "--dump-raw", str(dumps)]  # fmt: skip
    if cli(argv) != 0:
        raise SystemExit("predict --dump-raw failed")
    meta = json.loads((dumps / "metadata.json").read_text())
    shipped = preset_values("slimseg")
    for key in MULTI_FRAME:
        meta["slam_masking"].setdefault(key, shipped[key])
    (dumps / "metadata.json").write_text(json.dumps(meta))


def agreement(cpp: Path, python: Path) -> np.ndarray:
    """``float [F]``: per frame, the share of equal pixels of ``cpp/<stem>.pgm`` and
    ``python/<stem>.png``."""
    out = []
    for p in sorted(cpp.glob("*.pgm")):
        a = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        b = cv2.imread(str(python / f"{p.stem}.png"), cv2.IMREAD_UNCHANGED)
        out.append(float((a == b).mean()))
    return np.asarray(out)


def measure(sequence: Path, model: str, example: str, work: Path) -> dict:
    """One sequence's figures (see the module docstring)."""
    cv2.setNumThreads(1)
    dumps = work / "dumps"
    dump(sequence, model, dumps)
    stages: list[dict[str, float]] = []
    run_sequence(Predictor.from_path(model, threads=1), sequence, work / "dyn",
                 ChainConfig(masking=PRESETS["slimseg"]), progress=False,
                 observers=[lambda f, rgb, depth: stages.append(f.timing.stages)])  # fmt: skip
    cmd = [example, "--meta", str(dumps / "metadata.json"), "--dumps", str(dumps), "--out",
           str(work / "cpp"), "--strict"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})  # fmt: skip
    if done.returncode != 0:
        raise SystemExit(done.stderr)
    cpp_ms = float(re.search(r"multi-frame chain ([0-9.]+) ms", done.stdout).group(1))
    py_ms = float(np.mean([sum(s[k] for k in PYTHON_STAGES) for s in stages]))
    eq = agreement(work / "cpp", work / "dyn" / "masks")
    return {
        "sequence": str(sequence), "frames": len(eq),
        "frames_identical": int((eq == 1).sum()), "frames_below_99": int((eq < 0.99).sum()),
        "equal_px_mean_pct": round(100 * float(eq.mean()), 3),
        "equal_px_worst_pct": round(100 * float(eq.min()), 3),
        "python_ms": round(py_ms, 2), "cpp_ms": cpp_ms, "ratio": round(py_ms / cpp_ms, 2),
        "python_stages_ms": {k: round(float(np.mean([s[k] for s in stages])), 2)
                             for k in PYTHON_STAGES},
    }  # fmt: skip


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sequence", required=True, type=Path)
    ap.add_argument("--model", required=True)
    ap.add_argument("--example", required=True, help="the built slimseg_masks")
    ap.add_argument("--work", required=True, type=Path)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    r = measure(args.sequence, args.model, args.example, args.work)
    if args.json:
        print(json.dumps(r))
    else:
        print(f"{r['frames']} frames: {r['frames_identical']} identical, {r['frames_below_99']} "
              f"below 99 % equal pixels; mean {r['equal_px_mean_pct']} %, worst "
              f"{r['equal_px_worst_pct']} %; chain ms per frame: Python {r['python_ms']}, C++ "
              f"{r['cpp_ms']} ({r['ratio']}x)")  # fmt: skip
