"""Time per frame of each slam-eval engine at 640×480, and of making a masked frame.

    python benchmarks/slam_engines.py [--frames 60] [--sequence DIR]

Renders a synthetic ``walking_xyz`` sequence (``slimseg.data.synth``, seed 0) into a temporary
folder unless ``--sequence`` names one, builds a small DBoW2 vocabulary from its frames
(``slimseg.slam.vocab``, k=10, L=4), then times per frame: ORB-SLAM3 RGB-D tracking
(``track_rgbd`` only, fed as fast as it goes: its mapping threads compete for the same cores),
the dense RGB odometry (``cv2.Odometry``, RGB and RGB-D types), and the inpaint + zero-depth
step that turns a dynamic mask into the frame ORB-SLAM3 sees. Means over all frames, one run.
Needs the ``[slam]`` extra for ORB-SLAM3.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from slimseg.data.synth import generate
from slimseg.data.tum import TumSequence
from slimseg.slam.conditions import Condition, condition_frames
from slimseg.slam.engines import run_dense, run_orbslam3
from slimseg.slam.orbslam3_config import write_settings
from slimseg.slam.vocab import build_vocabulary
from slimseg.utils.table import format_table


def _dense_ms(frames: list, seq: TumSequence, kind: int) -> float:
    st = cv2.OdometrySettings()
    c = seq.camera
    st.setCameraMatrix(np.array([[c.fx, 0, c.cx], [0, c.fy, c.cy], [0, 0, 1]], np.float32))
    st.setMaxDepth(10.0)
    odo = cv2.Odometry(kind, st, cv2.OdometryAlgoType_COMMON)
    prev, total = None, 0.0
    for f in frames:
        t = time.perf_counter()
        gray = cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY)
        cur = cv2.OdometryFrame(
            image=gray, depth=f.depth_m, mask=np.full(gray.shape, 255, np.uint8)
        )
        odo.prepareFrame(cur)
        if prev is not None:
            odo.compute(cur, prev)
        total += time.perf_counter() - t
        prev = cur
    return 1000 * total / len(frames)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--sequence", type=Path, default=None)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.sequence
        if root is None:
            generate(Path(tmp) / "d", 1, 1, 64, 0, sequences=1, frames=args.frames,
                     progress=False, preset="walking_xyz")  # fmt: skip
            root = Path(tmp) / "d" / "sequences" / "seq_000"
        seq = TumSequence(root)
        t = time.perf_counter()
        raw = condition_frames(seq, Condition("raw", "raw"), limit=args.frames)
        rows = [
            [
                "load a raw frame (PNG RGB + depth)",
                f"{1000 * (time.perf_counter() - t) / len(raw):.1f}",
            ]
        ]
        h, w = raw[0].rgb.shape[:2]
        if (root / "dynamic").is_dir():
            t = time.perf_counter()
            condition_frames(seq, Condition("gt", "masked", masks=root / "dynamic"),
                             limit=args.frames)  # fmt: skip
            per = 1000 * (time.perf_counter() - t) / len(raw)
            rows.append(["load + inpaint + zero depth (gt masks)", f"{per:.1f}"])
        vocab = Path(tmp) / "voc.txt"
        build_vocabulary(sorted((root / "rgb").glob("*.png"))[: args.frames : 2], vocab)
        settings = write_settings(Path(tmp) / "s.yaml", seq.camera, w, h)
        run = run_orbslam3(raw, vocab, settings, realtime=False, log_path=Path(tmp) / "log")
        rows.append([f"ORB-SLAM3 RGB-D track_rgbd ({len(raw) - run.lost} OK)",
                     f"{run.ms_per_frame:.1f}"])  # fmt: skip
        dense = run_dense(raw, seq.camera)
        rows.append(["dense cv2.Odometry RGB (slam-eval's)", f"{dense.ms_per_frame:.1f}"])
        rows.append(
            ["dense cv2.Odometry RGB-D", f"{_dense_ms(raw, seq, cv2.OdometryType_RGB_DEPTH):.1f}"]
        )
    print(f"slam-eval engines, {w}x{h}, {len(raw)} frames (ms per frame)")
    print(format_table(["step", "ms/frame"], rows))


if __name__ == "__main__":
    main()
