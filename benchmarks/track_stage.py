"""Cost of the track stage per frame, side by side with the per-frame masking logic.

    python benchmarks/track_stage.py --sequence S            # ground-truth instances
    python benchmarks/track_stage.py --sequence S --model m.onnx --dropout 0.2:3

Runs ``slimseg dynamic``'s loop on the sequence with the stage off and on (preset ``coast``)
for ``fusion`` and ``fusion+epipolar``, alternating the two ``--repeats`` times, and prints the
stage's mean ms per frame (ORB matches for the camera motion, the fit, association,
prediction, coasting; in the epipolar mode also the check on the tracked objects, which the
per-frame logic runs too) next to the masking logic's, at the sequence's frame size. The
target in docs/tracking.md is <= 3 ms per frame at 640x480 on the CPU, without dense flow.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from slimseg.dynamic.annotations import AnnotationInstances, Dropout
from slimseg.dynamic.chain_config import TRACK_OFF, ChainConfig, TrackPlan
from slimseg.dynamic.track_settings import COAST
from slimseg.sequence.sequence_run import run_sequence
from slimseg.utils.table import format_table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequence", type=Path, required=True)
    ap.add_argument("--model", default=None, help="exported .onnx (default: gt instances)")
    ap.add_argument("--dropout", type=Dropout.parse, default=None, help="RATE:BURST (gt only)")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args()
    if args.model:
        from slimseg.deploy.predictor import Predictor

        source = Predictor.from_path(args.model, threads=args.threads)
    else:
        source = AnnotationInstances(args.sequence, args.dropout)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for mode in ("fusion", "fusion+epipolar"):
            got: dict[str, list[float]] = {"off": [], "on": [], "stage": []}
            for k in range(args.repeats):
                for name, plan in (("off", TRACK_OFF), ("on", TrackPlan(COAST))):
                    rep = run_sequence(
                        source,
                        args.sequence,
                        Path(tmp) / f"{mode}{k}{name}",
                        ChainConfig(mode=mode, track=plan),
                        progress=False,
                    )
                    got[name].append(rep.ms_per_frame["masking_logic"])
                    if name == "on":
                        got["stage"].append(rep.ms_per_frame["track_stage"])
                        frames = rep.frames
            off, on, stage = (statistics.median(got[n]) for n in ("off", "on", "stage"))
            rows.append([mode, f"{off:.2f}", f"{on:.2f}", f"{stage:.2f}", f"{on / off:.2f}"])
    print(f"{args.sequence}: {frames} frames, median of {args.repeats} alternating runs")
    print(format_table(["mode", "logic ms off", "logic ms on", "stage ms", "on / off"], rows))
    print("logic ms: ORB + instance extraction + masking per frame, the stage's time included")


if __name__ == "__main__":
    main()
