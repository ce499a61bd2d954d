"""``slimseg demo``: the embedded end-to-end job — synth data → train on the CPU → val → plots
→ ONNX → ORB-SLAM3 on a synthetic walking sequence with and without the model's masks."""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

from slimseg.cli.arg_types import count, multiple_of
from slimseg.cli.calibrate import default_report
from slimseg.cli.commands import COMMAND_HELP
from slimseg.data.coco import CocoDataset
from slimseg.data.config import load_data_config
from slimseg.data.dataset import ZooDataset
from slimseg.data.synth import generate
from slimseg.data.synth.presets import PRESETS
from slimseg.data.synth.world_frames import WorldSplits
from slimseg.engine.config import load_train_config
from slimseg.engine.preview import prediction_grid
from slimseg.errors import SlimsegError
from slimseg.eval.coco_eval import format_metrics_table
from slimseg.eval.plots import plot_results
from slimseg.eval.semantic_metrics import format_semantic_table
from slimseg.eval.validation import validate_dataset
from slimseg.models.checkpoint import load_weights
from slimseg.slam.demo_run import DEMO_RUNS
from slimseg.utils.atomic import write_json, write_png
from slimseg.utils.extras import install_command

DEMO_RECIPE = "cpu-demo"  # slimseg/configs/train/cpu-demo.yaml
#: The demo trains on the world it is judged on: 32 + 8 short sequences of the sequence
#: renderer, every 6th of 96 frames (512 + 128 frames at 640x480; docs/slam_defaults.md).
DEMO_WORLDS = WorldSplits(train=32, val=8, frames=96, step=6)
SLAM_SEED_OFFSET = 1  # the sequence's seed is --seed + 1: not the training images' seed
# The headline's warning: masks whose ATE exceeds this share of a camera that never moves have
# failed, whatever they gain over raw frames.
FLOOR_SHARE = 0.5


def add_parser(sub: argparse._SubParsersAction) -> None:
    from slimseg.calibrate.run import DEFAULT_BUDGET_S

    p = sub.add_parser(
        "demo",
        help=COMMAND_HELP["demo"],
        description="Generate the synthetic RGB-D dataset (no download), train a small variant "
        "on the CPU with configs/train/cpu-demo.yaml, validate its EMA weights with COCO mAP, "
        "and write training curves and a prediction grid. Then export the fused model to "
        "ONNX, render a synthetic walking sequence from another seed, and track it with "
        "ORB-SLAM3 RGB-D several times on raw frames, on frames masked by the model (fusion "
        "mode, slimseg masking defaults) and on frames masked by the ground truth, as "
        "slimseg slam-eval does: slam.png (trajectories, ATE bars) and the ATE table in "
        f"metrics.json. The SLAM stage needs {install_command('slam')} (GPL-3.0).",
    )
    p.add_argument("--out", default="runs/demo", help="demo folder (data/, train/, plots)")
    p.add_argument("--model", default="yolov8n-seg-gs-rep")
    p.add_argument("--epochs", type=count(1), default=None, help="default: the cpu-demo recipe's")
    p.add_argument("--imgsz", type=multiple_of(), default=320)
    p.add_argument(
        "--seq-train",
        type=count(0),
        default=DEMO_WORLDS.train,
        help=f"training worlds of the sequence world (default {DEMO_WORLDS.train}: "
        f"{DEMO_WORLDS.train * DEMO_WORLDS.per_world} frames at 640x480, presets mixed, "
        "seeds no evaluation sequence uses)",
    )
    p.add_argument(
        "--seq-val",
        type=count(0),
        default=DEMO_WORLDS.val,
        help=f"validation worlds (default {DEMO_WORLDS.val})",
    )
    p.add_argument(
        "--train-images",
        type=count(0),
        default=0,
        help="still images (square collages) mixed into training (default 0)",
    )
    p.add_argument("--val-images", type=count(0), default=0, help="still images mixed into val")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    g = p.add_argument_group("SLAM stage (export/, slam/, slam.png)")
    g.add_argument("--no-slam", action="store_true", help="stop after the plots")
    g.add_argument(
        "--slam-preset",
        default="walking_xyz",
        choices=sorted(PRESETS),
        help="synthetic sequence preset (default walking_xyz: a moving camera)",
    )
    g.add_argument("--slam-frames", type=count(1), default=100, help="sequence frames at 30 Hz")
    g.add_argument(
        "--slam-size",
        type=count(1),
        nargs=2,
        default=(640, 480),
        metavar=("W", "H"),
        help="sequence frame size (default 640 480, TUM's)",
    )
    g.add_argument(
        "--slam-seed",
        type=count(0),
        default=None,
        help=f"sequence seed (default --seed + {SLAM_SEED_OFFSET})",
    )
    g.add_argument(
        "--slam-runs",
        type=int,
        default=DEMO_RUNS,
        help=f"ORB-SLAM3 runs per condition (it is not deterministic; default {DEMO_RUNS})",
    )
    g.add_argument(
        "--vocab",
        type=Path,
        default=None,
        help="ORBvoc.txt (default: a small vocabulary built from the sequence)",
    )
    g.add_argument(
        "--calibration-budget",
        type=float,
        default=DEFAULT_BUDGET_S,
        metavar="SECONDS",
        help="time bound of the model's calibration before its SLAM run (slimseg calibrate; "
        f"default {DEFAULT_BUDGET_S:g})",
    )
    p.set_defaults(run=run)  # fmt: skip


def run(args: argparse.Namespace) -> int:
    from slimseg.engine.train import train

    start = time.perf_counter()
    out = Path(args.out)
    n = 4 if args.no_slam else 6
    if not args.no_slam:
        _check_slam_args(args)  # before training, not 11 minutes later
    data_yaml = out / "data" / "data.yaml"
    if data_yaml.is_file():
        print(f"[1/{n}] reusing the synthetic dataset in {data_yaml.parent}")
    else:
        worlds = WorldSplits(args.seq_train, args.seq_val, DEMO_WORLDS.frames, DEMO_WORLDS.step)
        frames = (worlds.train + worlds.val) * worlds.per_world
        print(
            f"[1/{n}] rendering {frames} training and validation frames from "
            f"{worlds.train}+{worlds.val} synthetic sequences"
            + (
                f" and {args.train_images}+{args.val_images} still images"
                if args.train_images
                else ""
            )
        )
        report = generate(
            out / "data",
            args.train_images,
            args.val_images,
            args.imgsz,
            args.seed,
            seq_size=tuple(args.slam_size),  # the frames the SLAM stage will mask
            progress=not args.quiet,
            worlds=worlds,
        )
        print(report.summary())
    cfg = load_train_config(DEMO_RECIPE).override(
        epochs=args.epochs, imgsz=args.imgsz, seed=args.seed
    )
    print(f"[2/{n}] training {args.model} for {cfg.epochs} epochs at {cfg.imgsz} px on the CPU")
    t_train = time.perf_counter()
    _, run_dir = train(
        args.model, data_yaml, cfg, out / "train", progress=not args.quiet, accelerator="cpu"
    )
    t_train = time.perf_counter() - t_train
    print(f"[3/{n}] validating the best EMA weights, fused (as deployed)")
    best = run_dir / "weights" / "best.pt"
    model, info = load_weights(best, fused=True)
    val_set = ZooDataset(CocoDataset.from_config(load_data_config(data_yaml), "val"), cfg.imgsz)
    metrics, _ = validate_dataset(model, val_set, cfg.batch, progress=False)
    semantic = "miou" in metrics  # msnet-*: mIoU / MPA instead of COCO mAP
    print(format_semantic_table(metrics) if semantic else format_metrics_table(metrics, info.names))
    write_json(out / "metrics.json", metrics, indent=1)
    print(f"[4/{n}] plots")
    curves = plot_results(run_dir / "results.csv", out / "results.png")
    grid = prediction_grid(model, val_set, info.names, count=8)
    preds = write_png(out / "predictions.png", grid)
    slam = None if args.no_slam else _slam_stage(args, best, cfg.imgsz, out, metrics)
    minutes = (time.perf_counter() - start) / 60
    if semantic:
        score = f"mIoU {metrics['miou']:.3f}, MPA {metrics['mpa']:.3f}"
        short = f"mIoU {metrics['miou']:.3f}"
    else:
        box, mask = metrics["box"], metrics.get("mask") or {}
        nan = float("nan")
        score = (
            f"box mAP50-95 {box['map50_95']:.3f} (mAP50 {box['map50']:.3f}), mask mAP50-95 "
            f"{mask.get('map50_95', nan):.3f} (mAP50 {mask.get('map50', nan):.3f})"
        )
        short = f"mask mAP50-95 {mask.get('map50_95', nan):.3f}"
    split = f"training {t_train / 60:.1f} min"
    if slam is not None:
        split += f", SLAM part {slam.seconds / 60:.1f} min: {slam.timing}"
    lines = [
        f"\ndone in {minutes:.1f} min: {score} at epoch {info.epoch + 1}",
        f"  time        {split} (wall clock; a loaded CPU stretches it)",
        f"  weights     {run_dir / 'weights'}/best.pt, last.pt",
        f"  resume      {run_dir / 'checkpoints' / 'last.ckpt'}",
        f"  logs        {run_dir / 'tb'} (tensorboard --logdir {run_dir / 'tb'})",
        f"  plots       {curves}, {preds}",
    ]
    if slam is not None:
        lines += slam.paths
    lines.append(f"  metrics     {out / 'metrics.json'}")
    print("\n".join(lines))
    print(f"{short}; {slam.result}" if slam is not None and slam.result else short)
    return 0


def _check_slam_args(args: argparse.Namespace) -> None:
    if args.slam_frames < 10:
        raise SlimsegError(f"--slam-frames {args.slam_frames}: need at least 10")
    if args.slam_runs < 1:
        raise SlimsegError(f"--slam-runs {args.slam_runs}: need at least 1")
    if min(args.slam_size) < 64:
        raise SlimsegError(f"--slam-size {args.slam_size[0]} {args.slam_size[1]}: both ≥ 64")
    if args.slam_seed is not None and args.slam_seed < 0:
        raise SlimsegError(f"--slam-seed {args.slam_seed} must be 0 or more")
    if not args.calibration_budget > 0:
        raise SlimsegError(f"--calibration-budget {args.calibration_budget}: expected seconds > 0")
    if args.vocab is not None and not Path(args.vocab).is_file():
        raise SlimsegError(f"--vocab {args.vocab} does not exist")


@dataclass
class _SlamSummary:
    seconds: float
    timing: str
    paths: list[str]
    result: str | None


def _slam_stage(
    args: argparse.Namespace, weights: Path, imgsz: int, out: Path, metrics: dict
) -> _SlamSummary:
    """Steps 5 and 6: export, then (with the [slam] extra) sequence, ORB-SLAM3, slam.png and
    metrics.json's ``slam`` entry."""
    from slimseg.slam import demo_run

    t0 = time.perf_counter()
    onnx = out / "export" / f"{args.model}.onnx"
    print(f"[5/6] exporting the fused best weights to FP32 ONNX at {imgsz} px")
    rep = demo_run.export_fp32(weights, onnx, imgsz)
    parity = ", ".join(f"{k} {v:.3g}" for k, v in rep.parity.items())
    print(f"wrote {rep.path} ({rep.nodes} nodes; parity vs fused torch: {parity})")
    seconds = {"export": time.perf_counter() - t0}
    paths = [f"  onnx        {rep.path} (+ {rep.sidecar.name})"]
    missing = demo_run.slam_extra_missing()
    if missing:
        print(f"[6/6] ORB-SLAM3 skipped: {' and '.join(missing)} not installed; to run it, "
              f"{install_command('slam')} (GPL-3.0)")  # fmt: skip
        return _SlamSummary(time.perf_counter() - t0, _timing(seconds), paths, None)
    seed = args.seed + SLAM_SEED_OFFSET if args.slam_seed is None else args.slam_seed
    s = demo_run.DemoSlamSettings(
        preset=args.slam_preset, seed=seed, frames=args.slam_frames, size=tuple(args.slam_size),
        runs=args.slam_runs, vocab=args.vocab, progress=not args.quiet,
    )  # fmt: skip
    folder = out / "slam"
    w, h = s.size
    print(f"[6/6] ORB-SLAM3 RGB-D on a synthetic {s.preset} sequence (seed {s.seed}, {s.frames} "
          f"frames, {w}x{h}): raw frames, slimseg masks, ground-truth masks, {s.runs} runs "
          "each")  # fmt: skip
    t = time.perf_counter()
    seq, reused = demo_run.prepare_sequence(folder, s)
    seconds["sequence"] = time.perf_counter() - t
    print(f"{'reusing' if reused else 'rendered'} the sequence in {seq}")
    t = time.perf_counter()
    vocab, built = demo_run.prepare_vocabulary(folder, seq, s)
    seconds["vocabulary"] = time.perf_counter() - t
    print(f"{'built' if built else 'using'} the vocabulary {vocab}")
    t = time.perf_counter()
    calibrated = _calibrate(onnx, args)
    seconds["calibration"] = time.perf_counter() - t
    if calibrated != onnx:
        paths += [f"  calibrated  {calibrated} (report: {default_report(onnx)}/)"]
    outcome = demo_run.evaluate(calibrated, seq, vocab, folder, s, print)
    seconds.update(outcome.seconds)
    fig = demo_run.write_figure(outcome, out / "slam.png", s, args.model)
    total = time.perf_counter() - t0
    table = demo_run.slam_table(outcome, s)
    table["seconds"] = {k: round(v, 1) for k, v in {**seconds, "total": total}.items()}
    metrics["slam"] = table
    write_json(out / "metrics.json", metrics, indent=1)
    from slimseg.slam.report import table_lines

    print(table_lines(outcome.rows, markdown=False))
    paths += [f"  slam        {fig}, {folder / 'results.md'} (runs.csv, trajectories/)"]
    return _SlamSummary(total, _timing(seconds), paths, _result(table))


def _calibrate(onnx: Path, args: argparse.Namespace) -> Path:
    """The demo's calibration of its model (``slimseg calibrate`` within
    ``--calibration-budget`` seconds, on sequences of the SLAM stage's frame size): the export
    beside it with its ``calibrated`` preset."""
    import importlib.util

    from slimseg.calibrate.confirm import CONFIRM_RUNS
    from slimseg.calibrate.run import CalibrationPlan
    from slimseg.cli.calibrate import calibrate_model

    if importlib.util.find_spec("optuna") is None:
        print(f"calibration skipped: Optuna is not installed ({install_command('calibrate')}); "
              "the shipped masking defaults are used")  # fmt: skip
        return onnx
    calibrated = onnx.with_name(onnx.stem + "_calibrated.onnx")
    budget = args.calibration_budget
    print(f"calibrating the masking settings for this model (at most {budget:.0f} s; "
          "slimseg calibrate)")  # fmt: skip
    plan = CalibrationPlan(
        model=onnx,
        budget_s=budget,
        size=tuple(args.slam_size),
        confirm_runs=min(args.slam_runs, CONFIRM_RUNS),
        progress=not args.quiet,
    )
    print(calibrate_model(plan, calibrated, default_report(onnx), print))
    return calibrated


def _timing(seconds: dict[str, float]) -> str:
    return ", ".join(f"{k} {v:.0f} s" for k, v in seconds.items())


def _result(table: dict) -> str:
    """``ATE raw A m → slimseg B m → ground-truth masks C m; a camera that never moves D m
    (median of N runs ...)`` and a warning where the masks did not help."""
    c = table["conditions"]

    def ate(key: str) -> str:
        v = c[key]["ate_median_m"]
        return "not scored" if v is None else f"{v:.3f} m"

    seq = table["sequence"]
    floor = table["still_camera_ate_m"]
    still = "" if floor is None else f"; a camera that never moves {floor:.3f} m"
    text = (
        f"ATE raw {ate('raw')} → slimseg {ate('slimseg')} → ground-truth masks "
        f"{ate('gt_masks')}{still} (median of {table['runs_per_condition']} ORB-SLAM3 runs "
        f"each, {seq['preset']} seed {seq['seed']}, {seq['frames']} frames)"
    )
    raw, ours = c["raw"], c["slimseg"]
    if raw["ate_median_m"] is None or ours["ate_median_m"] is None:
        return text
    if ours["ate_median_m"] >= raw["ate_median_m"]:
        text += "; the slimseg masks did not lower the ATE on this sequence"
    elif floor is not None and ours["ate_median_m"] > FLOOR_SHARE * floor:
        text += (
            f"; slimseg is above {FLOOR_SHARE:g}× the still camera's: its masks did little "
            "better than giving up on tracking"
        )
    elif ours["ate_max_m"] >= raw["ate_min_m"]:
        text += "; the slimseg and raw runs overlap (min–max): within ORB-SLAM3's run-to-run spread"
    return text
