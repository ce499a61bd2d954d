"""What the track stage buys: keypoint recall/precision, ghosts, stage cost and ORB-SLAM3 ATE
for a ladder of settings, side by side on the same sequences, runs and machine.

    python benchmarks/track_ladder.py --model runs/demo/export/yolov8n-seg-gs-rep.onnx \
        --sequence S1 --sequence S2 --runs 5 --out runs/track_ladder
    python benchmarks/track_ladder.py --gt-instances --ladder dropout --sequence S1 ...
    python benchmarks/track_ladder.py --model M.onnx --ladder segment-every --sequence S1 ...

Ladders (docs/tracking.md §4):
- ``track``: per-frame → tracks without coasting → coasting K = 1 / 3 / 5 (``fusion``), and
  the moving probability (``fusion+epipolar`` per frame vs tracked, K = 3);
- ``dropout`` (``--gt-instances``): ground-truth instances with bursts of misses injected
  (5 / 10 / 20 % of frames, bursts of 1 / 3 / 5), ``seg`` without vs with the stage;
- ``segment-every``: the model on every 1 / 2 / 3 / 5 frames, tracks carrying the masks;
  its rate from a budget of ``BUDGET_MS`` per frame; the model on its own thread (frames
  replayed in real time at the sequence's rate).

Every sequence also gets ``raw`` and ``gt`` (ground-truth masks) rows. Writes ``ladder.csv``,
``ladder.md`` and ``ladder.png`` (ATE median with min-max per rung and sequence) under
``--out``; a vocabulary is built from each sequence's frames unless ``--vocab`` is given.
Needs the ``[slam]`` extra (pyorbslam3, evo; GPL-3.0).
"""

from __future__ import annotations

import argparse
import csv
import math
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

from slimseg.data.tum import TumSequence
from slimseg.dynamic.annotations import Dropout
from slimseg.dynamic.chain_config import TRACK_OFF, ChainConfig, TrackPlan
from slimseg.dynamic.masking_settings import DEFAULT
from slimseg.dynamic.model_rate import ModelRate
from slimseg.dynamic.track_settings import COAST, NO_COAST
from slimseg.sequence.sequence_run import run_sequence
from slimseg.slam import session
from slimseg.slam.condition_runs import evaluate_condition
from slimseg.slam.conditions import Condition

BUDGET_MS = 25.0  # the segment-every ladder's budget rung


@dataclass(frozen=True)
class Rung:
    name: str
    mode: str
    track: TrackPlan = TRACK_OFF
    dropout: Dropout | None = None


def ladder(name: str) -> list[Rung]:
    """The named ladder's rungs, in order."""
    if name == "track":
        return [
            Rung("per-frame", "fusion"),
            Rung("tracks no coast", "fusion", TrackPlan(NO_COAST)),
            *[
                Rung(f"coast K={k}", "fusion", TrackPlan(COAST.with_values(max_coast=k)))
                for k in (1, 3, 5)
            ],
            Rung("per-frame +epipolar", "fusion+epipolar"),
            Rung("coast K=3 +moving p", "fusion+epipolar", TrackPlan(COAST)),
        ]
    if name == "dropout":
        rungs = [Rung("gt instances", "seg")]
        for rate in (0.05, 0.1, 0.2):
            for burst in (1, 3, 5):
                d = Dropout(rate, burst, seed=1)
                rungs += [
                    Rung(f"drop {rate:g}:{burst}", "seg", dropout=d),
                    Rung(f"drop {rate:g}:{burst} tracked", "seg", TrackPlan(COAST), d),
                ]
        return rungs
    if name == "segment-every":
        return [
            Rung("per-frame", "fusion"),
            *[
                Rung(f"every {n}", "fusion", TrackPlan(COAST, ModelRate.every_n(n)))
                for n in (1, 2, 3, 5)
            ],
            Rung(
                f"budget {BUDGET_MS:g} ms", "fusion", TrackPlan(COAST, ModelRate.budget(BUDGET_MS))
            ),
            Rung("own thread", "fusion", TrackPlan(COAST, ModelRate.own_thread())),
        ]
    raise SystemExit(f"unknown ladder {name!r}: track, dropout, segment-every")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--model", help="exported .onnx (or weights)")
    src.add_argument("--gt-instances", action="store_true")
    ap.add_argument("--sequence", type=Path, action="append", required=True)
    ap.add_argument("--ladder", default="track", choices=("track", "dropout", "segment-every"))
    ap.add_argument("--only", default=None, help="comma list of rung names to run")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--vocab", type=Path, default=None)
    ap.add_argument("--speed", type=float, default=1.0)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument(
        "--mode", default=None, help="mask mode of every rung (default: each rung's, fusion)"
    )
    ap.add_argument(
        "--set",
        default="",
        metavar="KEY=V,...",
        help="masking settings over the shipped defaults, e.g. min_static=0,t_o=0.6",
    )
    ap.add_argument(
        "--no-baselines", action="store_true", help="skip the raw and gt rows (already measured)"
    )
    args = ap.parse_args()
    args.masking = DEFAULT.with_values(
        **{k: float(v) if "." in v else int(v)
           for k, v in (kv.split("=") for kv in args.set.split(",") if kv)}
    )  # fmt: skip
    if args.mode:
        rungs_mode = args.mode
    rungs = ladder(args.ladder)
    if args.mode:
        rungs = [Rung(r.name, rungs_mode, r.track, r.dropout) for r in rungs]
    if args.only:
        want = {s.strip() for s in args.only.split(",")}
        rungs = [r for r in rungs if r.name in want]
    if args.ladder == "dropout" and not args.gt_instances:
        raise SystemExit("--ladder dropout acts on ground-truth instances: add --gt-instances")
    rows: list[dict] = []
    for seq_dir in args.sequence:
        rows += _sequence(args, seq_dir, rungs)
        _write(args.out, rows)
    print(f"written: {args.out / 'ladder.md'}, ladder.csv, ladder.png")


def _sequence(args: argparse.Namespace, seq_dir: Path, rungs: list[Rung]) -> list[dict]:
    from slimseg.slam.demo_run import VOCAB_IMAGES, VOCAB_K, VOCAB_LEVELS
    from slimseg.slam.vocab import build_vocabulary

    seq = TumSequence(seq_dir)
    label = seq_dir.name if seq_dir.name != "seq_000" else seq_dir.parent.parent.name
    folder = args.out / label
    folder.mkdir(parents=True, exist_ok=True)
    vocab = args.vocab
    if vocab is None:
        vocab = folder / "vocab.txt"
        if not vocab.is_file():
            paths = sorted((seq.root / "rgb").glob("*.png"))
            build_vocabulary(
                paths[:: max(1, len(paths) // VOCAB_IMAGES)], vocab, VOCAB_K, VOCAB_LEVELS
            )
    plan = session.Plan(
        sequence=seq, names=["raw"], runs=args.runs, vocab=vocab, speed=args.speed, progress=False
    )
    session.check_engine(plan.engine, vocab)
    gt = session.ground_truth(seq)
    cfg = session.engine_settings(plan, seq, folder)
    d = DEFAULT.dilation_px
    conds = [
        (Condition("raw", "raw"), {}),
        (Condition("gt", "masked", masks=seq.root / "dynamic", dilation_px=d), {}),
    ]
    if args.no_baselines:
        conds = []
    predictor = None
    for rung in rungs:
        inst = None
        if args.gt_instances:
            from slimseg.dynamic.annotations import AnnotationInstances

            inst = AnnotationInstances(seq.root, rung.dropout)
        elif predictor is None:
            predictor = session.make_predictor(args.model, False, seq.root, args.threads)
        out = folder / "masks" / "".join(c if c.isalnum() else "_" for c in rung.name)
        t0 = time.perf_counter()
        rep = run_sequence(
            inst or predictor,
            seq,
            out,
            ChainConfig(mode=rung.mode, masking=args.masking, track=rung.track),
            progress=False,
        )
        sc = rep.scores.get(rung.mode)
        loss = rep.recall_loss.summary() if rep.recall_loss else {}
        ms = rep.ms_per_frame
        info = {
            "mode": rung.mode,
            "masking": args.masking.describe(),
            "recall_pct": 100 * sc.recall if sc else None,
            "precision_pct": 100 * sc.precision if sc else None,
            "missed_on_dropouts_pct": loss.get("missed_on_dropouts_pct"),
            "dropout_frames_pct": loss.get("dropout_frames_pct"),
            "dropout_histogram": loss.get("dropout_histogram"),
            "ghost_pct": loss.get("ghost_pct"),
            "ghosts_after_exit": loss.get("ghosts_after_exit"),
            "model_ms": ms["model"],
            "logic_ms": ms["masking_logic"],
            "track_ms": ms.get("track_stage"),
            "total_ms": ms["model"] + ms["masking_logic"],
            "model_frames": rep.model_frames,
            "coasted": rep.coasted,
            "latency_median_ms": statistics.median(rep.latency_ms),
            "lag_median": statistics.median(rep.model_lags) if rep.model_lags else None,
            "model_ms_per_run": rep.model_ms_per_run,
        }
        print(
            f"{label} {rung.name}: masks in {time.perf_counter() - t0:.0f} s, "
            f"recall {_f(info['recall_pct'])} %, precision {_f(info['precision_pct'])} %"
        )
        conds.append((Condition(rung.name, "masked", masks=out / "masks"), info))
    rows = []
    for cond, info in conds:
        res = evaluate_condition(seq, cond, gt, cfg, folder / "trajectories")
        s = res.summary()
        ates = [r.score.ate_rmse for r in res.scored]
        print(
            f"{label} {cond.name}: ATE {_f(s['ate_rmse'], 4)} m "
            f"({_f(s['ate_min'], 4)}-{_f(s['ate_max'], 4)}), {s['status']}"
        )
        rows.append(
            {
                "sequence": label,
                "rung": cond.name,
                "ate_m": s["ate_rmse"],
                "ate_min": s["ate_min"],
                "ate_max": s["ate_max"],
                "ates": " ".join(f"{a:.4f}" for a in ates),
                "runs": s["runs"],
                "scored": s["scored_runs"],
                "late_max": s["late_max"],
                "status": s["status"],
                **info,
            }
        )
    return rows


def _f(v, nd: int = 1) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{nd}f}"


def _write(out: Path, rows: list[dict]) -> None:
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with (out / "ladder.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    cols = [
        "sequence",
        "rung",
        "ate_m",
        "ate_min",
        "ate_max",
        "recall_pct",
        "precision_pct",
        "ghost_pct",
        "missed_on_dropouts_pct",
        "track_ms",
        "total_ms",
        "status",
    ]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append(
            "| "
            + " | ".join(
                _f(r.get(c), 4 if c.startswith("ate") else 1)
                if not isinstance(r.get(c), str)
                else r[c]
                for c in cols
            )
            + " |"
        )
    (out / "ladder.md").write_text("\n".join(lines) + "\n")
    _plot(out / "ladder.png", rows)


def _plot(path: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seqs = list(dict.fromkeys(r["sequence"] for r in rows))
    fig, axes = plt.subplots(len(seqs), 1, figsize=(10, 3.2 * len(seqs)), squeeze=False)
    for ax, name in zip(axes[:, 0], seqs, strict=True):
        rs = [r for r in rows if r["sequence"] == name and r["ate_m"] is not None]
        x = range(len(rs))
        med = [r["ate_m"] for r in rs]
        lo = [r["ate_m"] - r["ate_min"] for r in rs]
        hi = [r["ate_max"] - r["ate_m"] for r in rs]
        colors = ["0.6" if r["rung"] in ("raw", "gt") else "tab:blue" for r in rs]
        ax.bar(x, med, color=colors, yerr=[lo, hi], capsize=3)
        for i, r in enumerate(rs):
            pts = [float(a) for a in r["ates"].split()] if r["ates"] else []
            ax.plot([i] * len(pts), pts, "k.", ms=3)
        ax.set_xticks(list(x), [r["rung"] for r in rs], rotation=30, ha="right", fontsize=8)
        ax.set_ylabel("ATE RMSE (m)")
        ax.set_title(f"{name}: median of ORB-SLAM3 runs, min–max whiskers, each run a dot")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
