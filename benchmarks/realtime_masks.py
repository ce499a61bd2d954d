"""Masks in real time on a CPU: what each model rate costs per frame and what it keeps.

    python benchmarks/realtime_masks.py --sequence S --model fp32.onnx --model int8.onnx \\
        --rates per-frame,1,3,budget:25,thread --threads 1

For every model file and rate, ``slimseg dynamic``'s loop (``fusion``, the ``slimseg``
masking preset) runs over the sequence, side by side in one process, models and rates
alternating over ``--repeats``. Rates: ``per-frame`` (no track stage: every frame judged
alone), ``N`` (``--track --segment-every N``), ``budget:MS`` (``--track --budget-ms MS``),
``thread`` (``--track --model-thread``: replayed in real time at the sequence's rate). Per
row: the loop's ms per frame in the model (inline runs; the thread's runs are shown apart),
in the masking logic and in the track stage, the total, its ratio to the first model's
per-frame total, the per-frame latency (median / p95), the model results' lag in frames, and
keypoint recall / precision against the sequence's ``dynamic/`` masks. ``--json`` prints the
rows. The model's own split (preprocess, inference, post-processing) is printed per file.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
from pathlib import Path

import numpy as np

from slimseg.data.tum import TumSequence
from slimseg.deploy.predictor import Predictor
from slimseg.dynamic.sequence_run import run_sequence
from slimseg.dynamic.track_run import TRACK_OFF, TrackPlan
from slimseg.dynamic.track_settings import COAST
from slimseg.utils.table import format_table


def parse_rate(text: str) -> TrackPlan:
    """``per-frame`` | ``N`` | ``budget:MS`` | ``thread`` → the run's plan."""
    if text == "per-frame":
        return TRACK_OFF
    if text == "thread":
        return TrackPlan(COAST, model_thread=True)
    if text.startswith("budget:"):
        return TrackPlan(COAST, budget_ms=float(text.split(":", 1)[1]))
    return TrackPlan(COAST, int(text))


def model_split(predictor: Predictor, seq: TumSequence, frames: int, conf: float) -> dict:
    """Mean ms per frame of the predictor's stages on ``frames`` frames spread over ``seq``."""
    acc: dict[str, float] = {}
    idx = np.linspace(0, len(seq.frames) - 1, frames).round().astype(int)
    for i in idx:
        pred = predictor.predict(seq.load(int(i))[0], conf=conf)
        for k, v in pred.timings.items():
            acc[k] = acc.get(k, 0.0) + v
        acc["detections"] = acc.get("detections", 0.0) + len(pred.scores)
    return {k: v / len(idx) for k, v in acc.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequence", type=Path, required=True)
    ap.add_argument("--model", action="append", required=True, help="repeat for each file")
    ap.add_argument("--rates", default="per-frame,1,2,3,5,budget:25,thread")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    seq = TumSequence(args.sequence)
    models = {Path(m).name: Predictor.from_path(m, threads=args.threads) for m in args.model}
    rates = args.rates.split(",")
    runs: dict[tuple[str, str], list[dict]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.repeats):
            for name, predictor in models.items():
                for rate in rates:
                    rep = run_sequence(predictor, seq, Path(tmp) / f"{r}", progress=False,
                                       track=parse_rate(rate))  # fmt: skip
                    runs.setdefault((name, rate), []).append(_row(rep))
    rows = [{"model": m, "rate": rate, **_median(v)} for (m, rate), v in runs.items()]
    base = rows[0]["total_ms"]
    for row in rows:
        row["x_first"] = row["total_ms"] / base
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(f"{seq.root}: {len(seq.frames)} frames, {args.threads} model thread(s), median of "
          f"{args.repeats} alternating run(s)")  # fmt: skip
    for name, predictor in models.items():
        for conf in (0.1, 0.05):
            split = model_split(predictor, seq, 10, conf)
            print(f"{name} at score >= {conf}: " + ", ".join(f"{k} {v:.1f}" for k, v in
                                                              split.items()))  # fmt: skip
    head = ["model", "rate", "model ms", "logic ms", "stage ms", "total ms", "x first",
            "thread model ms", "latency med / p95", "lag med (max)", "recall %",
            "precision %"]  # fmt: skip
    print(format_table(head, [_cells(r) for r in rows], markdown=True))


def _row(rep) -> dict:
    ms = rep.ms_per_frame
    sc = rep.scores.get("fusion")
    lat = np.asarray(rep.latency_ms)
    lags = np.asarray(rep.model_lags) if rep.model_lags else np.zeros(1)
    return {
        "model_ms": ms["model"],
        "logic_ms": ms["masking_logic"],
        "stage_ms": ms.get("track_stage", 0.0),
        "total_ms": ms["model"] + ms["masking_logic"],
        "thread_model_ms": ms.get("model_thread", 0.0),
        "latency_median_ms": float(np.median(lat)),
        "latency_p95_ms": float(np.percentile(lat, 95)),
        "late_max_ms": float(max(rep.late_ms, default=0.0)),
        "lag_median": float(np.median(lags)),
        "lag_max": int(lags.max()),
        "model_frames": rep.model_frames,
        "recall_pct": 100 * sc.recall if sc else float("nan"),
        "precision_pct": 100 * sc.precision if sc else float("nan"),
        "stage_parts_ms": rep.stage_parts_ms,
    }


def _median(runs: list[dict]) -> dict:
    out = {}
    for k, v in runs[0].items():
        if isinstance(v, dict):
            out[k] = {p: statistics.median(r[k][p] for r in runs) for p in v}
        else:
            out[k] = statistics.median(r[k] for r in runs)
    return out


def _cells(r: dict) -> list[str]:
    return [r["model"], r["rate"], f"{r['model_ms']:.1f}", f"{r['logic_ms']:.1f}",
            f"{r['stage_ms']:.1f}", f"{r['total_ms']:.1f}", f"{r['x_first']:.2f}",
            f"{r['thread_model_ms']:.1f}" if r["thread_model_ms"] else "-",
            f"{r['latency_median_ms']:.0f} / {r['latency_p95_ms']:.0f}",
            f"{r['lag_median']:g} ({r['lag_max']})", f"{r['recall_pct']:.1f}",
            f"{r['precision_pct']:.1f}"]  # fmt: skip


if __name__ == "__main__":
    main()
