"""Digests of ``slimseg dynamic``'s outputs on a small synthetic sequence, to compare versions.

Ground-truth instances with dropouts, a tiny YOLOv8-seg and an MSNET class-map model (both
fitted as the tests fit them), every mode, without and with the track stage (every frame,
every 2nd, no-coast every 3rd) and other masking settings: the masks, ``frames.csv`` less its
timing column, ``tracks.csv`` and the printed scores. Run it on each version and compare::

    PYTHONPATH=. python tools/mask_digests.py before.json .   # the old checkout
    PYTHONPATH=. python tools/mask_digests.py after.json .    # the new one

Equal JSON files: byte-identical masks (and CSVs, and scores) in every case listed.
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, sys.argv[2] if len(sys.argv) > 2 else ".")
from slimseg.cli.main import main
from slimseg.data.synth.sequence import write_sequence
from slimseg.data.tum import TumSequence
from slimseg.models.checkpoint import WeightsInfo, save_weights
from slimseg.models.registry import build_model
from tests.conftest import batchnorm_from, class_map_weights, open_class_bias

MODES = ("seg", "box", "fusion", "box+depth-ransac", "semantic+epipolar", "fusion+epipolar")
TRACKS = {
    "off": [],
    "track": ["--track"],
    "track-e2": ["--track", "--rate", "2"],
    "nocoast-e3": ["--track", "no-coast", "--rate", "3"],
}


def digest(folder: Path) -> str:
    h = hashlib.sha1()
    files = sorted((folder / "masks").glob("*.png"))
    assert files, folder
    for p in files:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return f"{len(files)}:{h.hexdigest()[:16]}"


def csv_digest(folder: Path) -> str:
    """frames.csv without its timing column, and tracks.csv."""
    import csv

    h = hashlib.sha1()
    with open(folder / "frames.csv") as f:
        for row in csv.DictReader(f):
            row.pop("model_ms", None)
            h.update(repr(sorted(row.items())).encode())
    tracks = folder / "tracks.csv"
    if tracks.is_file():
        h.update(tracks.read_bytes())
    return h.hexdigest()[:16]


def report_digest(text: str) -> str:
    """The printed scores, epipolar tally, rule and recall-loss lines (no timings)."""
    keep = []
    on = False
    for line in text.splitlines():
        if line.startswith("dynamic keypoints vs ground truth"):
            on = True
        if line.startswith(("masking rule", "where recall is lost")) or on:
            keep.append(line)
    return hashlib.sha1("\n".join(keep).encode()).hexdigest()[:16] + f":{len(keep)}"


def yolo_weights(seq: Path, path: Path) -> Path:
    import cv2

    tum = TumSequence(seq)
    rgb = np.stack([cv2.resize(tum.load(i)[0], (64, 64)) for i in range(4)])
    torch.manual_seed(0)
    model = build_model("yolov8n-seg", num_classes=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        batchnorm_from(model, torch.from_numpy(rgb).permute(0, 3, 1, 2).float() / 255)
    fused = open_class_bias(model).fuse()
    info = WeightsInfo(fused.spec, ["person", "chair"], [1.0, 0.1], train_config={"imgsz": 64})
    return save_weights(path, fused, info)


def run(tmp: Path, name: str, argv: list[str], out: dict) -> None:
    o = tmp / name.replace("/", "_").replace("+", "p")
    import contextlib
    import io

    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            rc = main(["dynamic", *argv, "--out", str(o), "--quiet", "--threads", "1"])
        out[name] = digest(o) if rc == 0 else f"rc={rc}"
        if rc == 0:
            out[name + " +csv"] = csv_digest(o)
            out[name + " +report"] = report_digest(buf.getvalue())
    except Exception as e:
        out[name] = f"error {type(e).__name__}: {str(e)[:80]}"
    print(name, out[name], flush=True)


def runs() -> dict:
    out: dict[str, str] = {}
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        seq = tmp / "seq"
        write_sequence(seq, seed=5, index=0, frames=24, size=(320, 240), preset="walking_xyz")
        gt = ["--gt-instances", "--gt-dropout", "0.2:3:1", "--sequence", str(seq)]
        for mode in MODES:
            for tn, targs in TRACKS.items():
                run(tmp, f"gt/{mode}/{tn}", [*gt, "--mode", mode, *targs], out)
        for mode in ("seg", "fusion", "fusion+epipolar", "box"):
            for tn in ("off", "track"):
                run(
                    tmp,
                    f"gt-papers/{mode}/{tn}",
                    [*gt, "--mode", mode, "--preset", "papers", *TRACKS[tn]],
                    out,
                )
        for mode in ("fusion", "seg", "box+depth-ransac"):
            for tn in ("off", "track"):
                run(
                    tmp,
                    f"gt-nodepth/{mode}/{tn}",
                    [*gt, "--mode", mode, "--no-depth", *TRACKS[tn]],
                    out,
                )
        for mode in ("semantic+epipolar", "fusion+epipolar", "fusion"):
            for tn in ("off", "track"):
                run(
                    tmp,
                    f"gt-epidepth/{mode}/{tn}",
                    [*gt, "--mode", mode, "--epipolar-depth", *TRACKS[tn]],
                    out,
                )
        run(
            tmp,
            "gt-eq1-odds/fusion/off",
            [*gt, "--mode", "fusion", "--set", "rule=eq1", "--set", "motion_odds=3"],
            out,
        )
        yolo = yolo_weights(seq, tmp / "yolo.pt")
        for mode in MODES:
            for tn in ("off", "track", "track-e2"):
                run(
                    tmp,
                    f"yolo/{mode}/{tn}",
                    ["--model", str(yolo), "--sequence", str(seq), "--mode", mode, *TRACKS[tn]],
                    out,
                )
        msnet = class_map_weights(seq, tmp / "msnet.pt")
        for mode in MODES:
            for tn in ("off", "track"):
                run(
                    tmp,
                    f"msnet/{mode}/{tn}",
                    ["--model", str(msnet), "--sequence", str(seq), "--mode", mode, *TRACKS[tn]],
                    out,
                )
    return out


if __name__ == "__main__":
    res = runs()
    Path(sys.argv[1]).write_text(json.dumps(res, indent=1, sort_keys=True))
