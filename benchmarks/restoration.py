"""Per-frame cost of VTD-SLAM's geometry and restoration steps at 640×480.

    python benchmarks/restoration.py [--frames 31] [--targets 5]

Renders a synthetic TUM sequence (``slimseg.data.synth``, seed 0) into a temporary folder, then
times, per frame: ORB features + the epipolar motion check on the ground-truth instance masks
(with and without the depth-aided residual), and background restoration of the ground-truth
dynamic region: reference selection + PatchMatch (ours) against ``cv2.inpaint`` Telea on RGB
and depth. Medians over the target frames (the middle ones, so the ±15-frame window is full);
one run, one process, no warm-up beyond the first call.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from slimseg.data.synth import generate
from slimseg.data.tum import TumSequence, mask_name
from slimseg.dynamic.annotations import AnnotationInstances
from slimseg.dynamic.epipolar import check_motion, orb_features
from slimseg.dynamic.restore import (
    STRIDE,
    WINDOW,
    FrameData,
    removed_region,
    restore_frame,
    select_references,
)
from slimseg.utils.table import format_table


def _ms(fn, *args, **kwargs) -> tuple[float, object]:
    t = time.perf_counter()
    out = fn(*args, **kwargs)
    return 1000 * (time.perf_counter() - t), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=31)
    ap.add_argument("--targets", type=int, default=5)
    args = ap.parse_args()
    if args.targets < 1 or args.frames < args.targets + 2:
        ap.error(
            f"--frames {args.frames} --targets {args.targets}: the targets are middle frames "
            "with a neighbour on each side, so give --targets >= 1 and --frames >= --targets + 2"
        )
    with tempfile.TemporaryDirectory() as tmp:
        generate(
            Path(tmp),
            1,
            1,
            64,
            0,
            sequences=1,
            frames=args.frames,
            seq_size=(640, 480),
            progress=False,
        )
        seq_dir = Path(tmp) / "sequences" / "seq_000"
        seq, ann = TumSequence(seq_dir), AnnotationInstances(seq_dir)
        cam = seq.camera.pinhole
        frames = []
        for i in range(len(seq)):
            rgb, depth, stamp = seq.load(i)
            gt = cv2.imread(str(seq_dir / "dynamic" / mask_name(stamp)), cv2.IMREAD_GRAYSCALE)
            frames.append((rgb, depth, stamp, removed_region(gt)))
        mid = len(frames) // 2
        targets = range(max(1, mid - args.targets // 2), mid - args.targets // 2 + args.targets)
        t = {k: [] for k in ("orb", "epi", "epi_depth", "select", "patchmatch", "telea")}
        pixels = []
        data = {}
        for i in range(len(frames)):
            rgb, depth, _, removed = frames[i]
            data[i] = FrameData.build(rgb, depth, removed)
        for i in targets:
            rgb, depth, stamp, removed = frames[i]
            pred = ann.for_stamp(stamp)
            regions = pred.masks[np.asarray(pred.mobility) > 0.25]
            prev = orb_features(frames[i - 1][0])
            ms, cur = _ms(orb_features, rgb)
            t["orb"].append(ms)
            t["epi"].append(_ms(check_motion, prev, cur, regions)[0])
            ms, _ = _ms(check_motion, prev, cur, regions, depth_m=frames[i - 1][1], camera=cam)
            t["epi_depth"].append(ms)
            cands = {
                j: data[j]
                for j in range(i - WINDOW, i + WINDOW + 1, STRIDE)
                if j != i and 0 <= j < len(frames)
            }
            ms, refs = _ms(select_references, data[i], cands)
            t["select"].append(ms)
            ms, _ = _ms(restore_frame, data[i], [(cands[r.index], r) for r in refs])
            t["patchmatch"].append(ms)
            m8 = removed.astype(np.uint8)
            t0 = time.perf_counter()
            cv2.inpaint(rgb, m8, 3, cv2.INPAINT_TELEA)
            cv2.inpaint(np.where(removed, 0, depth).astype(np.float32), m8, 3, cv2.INPAINT_TELEA)
            t["telea"].append(1000 * (time.perf_counter() - t0))
            pixels.append(int(removed.sum()))
    med = {k: statistics.median(v) for k, v in t.items()}
    ours = med["select"] + med["patchmatch"]
    print(
        f"640x480, {len(pixels)} frames, median removed region {statistics.median(pixels)} px, "
        "1000 ORB features"
    )
    rows = [
        ["ORB features (1000)", round(med["orb"], 1), "-"],
        ["epipolar check", round(med["epi"], 1), "-"],
        ["epipolar check + depth (PnP)", round(med["epi_depth"], 1), "-"],
        ["reference selection", round(med["select"], 1), round(med["select"] / med["telea"], 1)],
        [
            "PatchMatch fill (RGB + depth)",
            round(med["patchmatch"], 1),
            round(med["patchmatch"] / med["telea"], 1),
        ],
        ["restoration total (ours)", round(ours, 1), round(ours / med["telea"], 1)],
        ["cv2.inpaint Telea (RGB + depth)", round(med["telea"], 1), 1.0],
    ]
    print(format_table(["step", "ms / frame", "× Telea"], rows))


if __name__ == "__main__":
    main()
