"""``slimseg dynamic``: the SLAM-facing masking logic over a TUM RGB-D sequence."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from slimseg.deploy.predictor import Predictor
from slimseg.dynamic.pipeline import MODES
from slimseg.dynamic.sequence_run import run_sequence
from slimseg.utils.table import format_table


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "dynamic",
        help="dynamic-keypoint masks for a TUM RGB-D sequence (+ precision/recall with GT)",
        description="Run a model and the reference masking logic (Eq. 1/3/4 of the substation "
        "paper, YOLO-SLAM's depth-RANSAC) on a TUM-layout sequence. Writes masks/<rgb "
        "timestamp>.png (255 = dynamic), frames.csv and overlay.png; with ground-truth "
        "dynamic/ masks, prints keypoint precision and recall of every mode.",
    )
    p.add_argument("--model", required=True, help="exported .onnx, or weights .pt/.ckpt")
    p.add_argument("--sequence", required=True, help="folder with rgb.txt and depth.txt")
    p.add_argument("--out", default="runs/dynamic")
    p.add_argument("--mode", default="fusion", choices=MODES)
    p.add_argument("--conf", type=float, default=0.25)
    p.add_argument("--keypoints", type=int, default=1000, help="ORB features per frame")
    p.add_argument("--min-static", type=int, default=100, help="Eq. 1: static points needed")
    p.add_argument("--dilation", type=int, default=0, help="mask dilation in pixels")
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    predictor = Predictor.from_path(args.model, threads=args.threads)
    out = Path(args.out)
    report = run_sequence(
        predictor,
        Path(args.sequence),
        out,
        args.mode,
        args.conf,
        args.keypoints,
        args.min_static,
        args.dilation,
        progress=not args.quiet,
    )
    timing = ", ".join(f"{k} {v:.1f} ms" for k, v in report.ms_per_frame.items())
    print(f"{report.frames} frames, mode {args.mode}: masks in {out / 'masks'}; per frame {timing}")
    if report.scores:
        rows = [
            [m, s.tp, s.fp, s.fn, _pct(s.precision), _pct(s.recall)]
            for m, s in report.scores.items()
            if s.tp + s.fp + s.fn + s.tn
        ]
        print("dynamic keypoints vs ground truth:")
        print(format_table(["mode", "TP", "FP", "FN", "precision %", "recall %"], rows))
    if report.skipped:
        print(f"{len(report.skipped)} frame(s) without ground truth, e.g. {report.skipped[0]}")
    return 0


def _pct(v: float) -> str:
    return "-" if math.isnan(v) else f"{100 * v:.1f}"
