"""Masks in real time on a CPU: what each model rate costs per frame and what it keeps.

    python benchmarks/realtime_masks.py --sequence S --model fp32.onnx --model int8.onnx \\
        --rates per-frame,3,budget:25,thread,thread-camera --threads 1

Every row is a loop over the public per-frame object (``slimseg.Masker``, mode ``fusion``,
the export's recommended masking settings), side by side in one process, models and rates
alternating over ``--repeats``. The frames (and their ground-truth ``dynamic/`` masks) are
read into memory first, so the loop pays only what a SLAM front end would. Rates:
``per-frame`` (no track stage: every frame judged alone), ``N`` (track stage, model on every
N-th frame), ``budget:MS``, ``thread`` (the model on its own thread, frames arriving at the
sequence's timestamps, late results moved by each object's own ORB matches) and
``thread-camera`` (the same, late results and carried masks moved by the camera motion and
the track's velocity only: ``own_matches`` 0, the mechanism before), ``lag:L`` and
``lag:L-camera`` (the own thread emulated without a clock: every result exactly L frames late,
the same on any machine; the loop's time then includes the model's inline runs). Per row:
the loop's ms per frame in the model (inline runs; the thread's runs are shown apart), in
ORB + track stage + masking logic, of which the stage, the total and its ratio to the first
row's total, the latency per frame (median / p95), the results' lag in frames, keypoint
recall / precision against ``dynamic/`` and recall as a share of the per-frame row of the
same model. ``--json`` prints the rows.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import cv2
import numpy as np

from slimseg import Masker, ModelRate
from slimseg.data.images import decode_file
from slimseg.data.tum import TumSequence, mask_name
from slimseg.deploy.metadata import masking_from_metadata
from slimseg.deploy.predictor import Predictor
from slimseg.dynamic.chain_config import ChainConfig, TrackPlan
from slimseg.dynamic.frame_masker import FrameMasker, segmenter_for
from slimseg.dynamic.model_feed import FedDetections
from slimseg.dynamic.track_settings import COAST, detection_floor
from slimseg.sequence.sequence_report import ModeScore, at_keypoints
from slimseg.utils.table import format_table


class FixedLagFeed:
    """The model on its own thread, emulated without a clock: frame 0 waits for its own
    result, then each result arrives ``lag`` frames after the frame it was computed on and
    the worker takes the current frame (what a thread whose runs last ``lag`` frames does,
    the same on every machine: ``lag:L`` rows)."""

    def __init__(self, run, lag: int) -> None:
        self.run, self.lag = run, lag
        self.job: tuple[int, object] | None = None
        self.lags: list[int] = []
        self.model_runs, self.model_s = 0, 0.0

    def frame(self, i: int, rgb: np.ndarray, stamp: float) -> FedDetections:
        got = FedDetections(None)
        if i == 0:
            got = FedDetections(self.run(rgb, stamp), 0, 0)
        elif self.job is not None and i - self.job[0] >= self.lag:
            got = FedDetections(self.job[1], self.job[0], i - self.job[0])
            self.job = None
        if got.objects is not None:
            self.lags.append(got.lag)
            self.model_runs += 1
        if self.job is None and i > 0:
            self.job = (i, self.run(rgb, stamp))
        return got

    def other_time(self, seconds: float) -> None:
        """A fixed schedule."""

    def close(self) -> None:
        """Nothing runs apart."""


def masker_for(predictor: Predictor, rate: str, fps: float) -> FrameMasker:
    """The row's object: ``per-frame`` without the stage, the rest with it; ``*-camera``:
    late results and carried masks moved by the camera motion and the track velocity only
    (``own_matches`` 0, the mechanism before)."""
    if rate == "per-frame":
        return Masker.from_predictor(predictor, fps=fps)
    base, camera = rate.removesuffix("-camera"), rate.endswith("-camera")
    track = COAST.with_values(own_matches=0) if camera else COAST
    if base.startswith("lag:"):
        masking = masking_from_metadata(predictor.metadata)
        floor = detection_floor(masking.conf, track)
        segment = segmenter_for(predictor)
        feed = FixedLagFeed(lambda rgb, stamp: segment(rgb, stamp, floor), int(base[4:]))
        config = ChainConfig(masking=masking, track=TrackPlan(track), fps=fps)
        return FrameMasker(segment, predictor.mobility, config, feed=feed)
    return Masker.from_predictor(predictor, track=track, rate=ModelRate.parse(base), fps=fps)


def run(masker: FrameMasker, frames: list, truths: list, stamps: list[float]) -> dict:
    """One pass over the in-memory frames; frames arrive at their timestamps when the model
    has its own thread (the loop waits for each), at once otherwise."""
    score, carried = ModeScore(), ModeScore()
    lat, model, masking, late = [], [], [], []
    live = masker.config.track.rate.thread
    with masker:
        start = None
        for (rgb, depth), truth, stamp in zip(frames, truths, stamps, strict=True):
            if live:
                start = start or (time.perf_counter(), stamp)
                due = start[0] + stamp - start[1]
                now = time.perf_counter()
                if due > now:
                    time.sleep(due - now)
                late.append(1000 * max(time.perf_counter() - due, 0.0))
            out = masker.step(rgb, depth, stamp)
            at = at_keypoints(truth, out.keypoints)
            score.add(out.dynamic, at)
            if not out.model_ran:
                carried.add(out.dynamic, at)
            lat.append(out.timing.latency)
            model.append(out.timing.model)
            masking.append(out.timing.masking)
        feed, n = masker.feed, len(frames)
        stage = masker.stage
    lags = np.asarray(feed.lags or [0])
    return {
        "model_ms": float(np.mean(model)),
        "logic_ms": float(np.mean(masking)),
        "stage_ms": 0.0 if stage is None else stage.ms_per_frame,
        "total_ms": float(np.mean(model) + np.mean(masking)),
        "thread_model_ms": 1000 * feed.model_s / n if live else 0.0,
        "latency_median_ms": float(np.median(lat)),
        "latency_p95_ms": float(np.percentile(lat, 95)),
        "late_max_ms": float(max(late, default=0.0)),
        "lag_median": float(np.median(lags)),
        "lag_max": int(lags.max()),
        "model_frames": feed.model_runs,
        "recall_pct": 100 * score.recall,
        "precision_pct": 100 * score.precision,
        "recall_carried_pct": 100 * carried.recall,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequence", type=Path, required=True)
    ap.add_argument("--model", action="append", required=True, help="repeat for each file")
    ap.add_argument("--rates", default="per-frame,1,2,3,5,budget:25,thread,thread-camera")
    ap.add_argument("--frames", type=int, default=0, help="first N frames (0: all)")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    seq = TumSequence(args.sequence)
    count = len(seq) if args.frames <= 0 else min(args.frames, len(seq))
    frames, truths, stamps = [], [], []
    for i in range(count):
        rgb, depth, stamp = seq.load(i)
        gt = decode_file(seq.root / "dynamic" / mask_name(stamp), cv2.IMREAD_GRAYSCALE)
        if gt is None:
            raise SystemExit(f"{seq.root / 'dynamic'}: no ground-truth mask for {stamp:.6f}")
        frames.append((rgb, depth))
        truths.append(gt > 0)
        stamps.append(stamp)
    models = {Path(m).name: Predictor.from_path(m, threads=args.threads) for m in args.model}
    rates = args.rates.split(",")
    runs: dict[tuple[str, str], list[dict]] = {}
    for _ in range(args.repeats):
        for name, predictor in models.items():
            for rate in rates:
                row = run(masker_for(predictor, rate, seq.fps), frames, truths, stamps)
                runs.setdefault((name, rate), []).append(row)
    rows = [{"model": m, "rate": rate, **_median(v)} for (m, rate), v in runs.items()]
    base = rows[0]["total_ms"]
    per_frame = {r["model"]: r["recall_pct"] for r in rows if r["rate"] == "per-frame"}
    for row in rows:
        row["x_first"] = row["total_ms"] / base
        ref = per_frame.get(row["model"], rows[0]["recall_pct"])
        row["recall_share_pct"] = 100 * row["recall_pct"] / ref if ref else float("nan")
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(f"{seq.root}: {count} frames, {args.threads} model thread(s), median of "
          f"{args.repeats} alternating run(s)")  # fmt: skip
    head = ["model", "rate", "model ms", "masking ms", "of which stage", "total ms", "x first",
            "thread model ms", "latency med / p95", "lag med (max)", "recall %",
            "precision %", "recall / per-frame %",
            "recall without a result %"]  # fmt: skip
    print(format_table(head, [_cells(r) for r in rows], markdown=True))


def _median(runs: list[dict]) -> dict:
    return {k: statistics.median(r[k] for r in runs) for k in runs[0]}


def _cells(r: dict) -> list[str]:
    return [r["model"], r["rate"], f"{r['model_ms']:.1f}", f"{r['logic_ms']:.1f}",
            f"{r['stage_ms']:.1f}", f"{r['total_ms']:.1f}", f"{r['x_first']:.2f}",
            f"{r['thread_model_ms']:.1f}" if r["thread_model_ms"] else "-",
            f"{r['latency_median_ms']:.0f} / {r['latency_p95_ms']:.0f}",
            f"{r['lag_median']:g} ({r['lag_max']})", f"{r['recall_pct']:.1f}",
            f"{r['precision_pct']:.1f}", f"{r['recall_share_pct']:.0f}",
            f"{r['recall_carried_pct']:.1f}"]  # fmt: skip


if __name__ == "__main__":
    main()
