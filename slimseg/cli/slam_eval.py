"""``slimseg slam-eval``: ORB-SLAM3 (or dense odometry) with and without the masks, ATE/RPE."""

from __future__ import annotations

import argparse
import json
import sys
from functools import partial
from pathlib import Path

from slimseg.cli.arg_types import count, number, threads
from slimseg.cli.bag_args import add_bag_args, bag_options_from_args
from slimseg.cli.commands import COMMAND_HELP
from slimseg.cli.rerun_args import add_rerun_arg, rerun_path
from slimseg.cli.settings_args import add_settings_args, settings_from_args
from slimseg.cli.track_args import add_dropout_arg, dropout_from_args
from slimseg.dynamic.modes import KEYPOINTS, MAX_KEYPOINTS, MODES
from slimseg.errors import SlimsegError
from slimseg.slam.diagnostic import DIAGNOSTIC
from slimseg.utils.atomic import staged_dir
from slimseg.utils.extras import install_command

SPECIAL = ("raw", "gt", "oracle")
DEFAULT_MODES = "raw,gt,oracle,fusion"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "slam-eval",
        help=COMMAND_HELP["slam-eval"],
        description="Run ORB-SLAM3 RGB-D (pyorbslam3) or a dense RGB odometry on a TUM-layout "
        "sequence once per condition - raw frames, each mode's dynamic masks (computed as "
        "slimseg dynamic does, or read from --masks), ground-truth masks, restored frames "
        "(--restore), the true static background of a synthetic sequence - and score every "
        "trajectory with evo against groundtruth.txt. Writes per-run TUM trajectories, "
        "results.csv, runs.csv, results.md and trajectories.png. With --sweep, evaluates one "
        "mask mode under many masking settings instead (sweep.csv, sweep.md, sweep.png; "
        f"docs/slam_defaults.md). Needs {install_command('slam')} (pyorbslam3 and evo, "
        "GPL-3.0).",
    )
    p.add_argument(
        "--sequence",
        required=True,
        type=Path,
        action="append",
        help="TUM-layout folder (repeat it with --sweep for several sequences), or a ROS bag "
        "(.bag, .mcap, rosbag2 folder; needs slimseg[ros]; docs/bags.md)",
    )
    add_bag_args(p)
    gt = p.add_argument_group("ground truth (default: the folder's groundtruth.txt)")
    gt.add_argument("--groundtruth", type=Path, help="a TUM groundtruth.txt for the sequence")
    gt.add_argument(
        "--pose-topic", help="bag topic with the true poses (PoseStamped, Odometry or tf)"
    )
    gt.add_argument("--pose-frame", help="with a tf --pose-topic: the child frame to use")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--model", help="exported .onnx (or weights) for the mask modes")
    src.add_argument("--masks", type=Path, help="a slimseg dynamic output (masks/<ts>.png)")
    src.add_argument(
        "--gt-instances",
        action="store_true",
        help="mask modes from the sequence's annotations.json instances instead of a model "
        "(synthetic sequences): the masking logic on perfect detections",
    )
    add_dropout_arg(p)
    p.add_argument(
        "--modes",
        default=None,
        help=f"comma list of conditions: raw, gt, oracle and mask modes {', '.join(MODES)} "
        f"(default: {DEFAULT_MODES} with --model, raw,gt,oracle,masks with --masks, else "
        "raw,gt,oracle; gt/oracle are skipped where the sequence lacks dynamic/ or "
        f"background/); with --masks also {' and '.join(DIAGNOSTIC)}: the masks at perfect "
        "precision and at perfect recall (docs/slam_eval.md): which of the two closes the gap to "
        "gt says where the masks' ATE is lost",
    )
    p.add_argument(
        "--restore",
        nargs="?",
        const="all",
        default=None,
        metavar="CONDITIONS",
        help="also evaluate PatchMatch-restored frames of the masked conditions (all, or a "
        "comma list such as gt,fusion)",
    )
    p.add_argument("--engine", choices=("orbslam3", "dense"), default="orbslam3")
    p.add_argument("--runs", type=count(1), default=3, help="ORB-SLAM3 runs per condition")
    p.add_argument("--vocab", type=Path, help="ORBvoc.txt, or one from slimseg slam vocab")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--json", action="store_true", help="print the results table as JSON")
    p.add_argument(
        "--keypoints",
        type=count(1, MAX_KEYPOINTS),
        default=KEYPOINTS,
        help="ORB features (mask modes)",
    )
    add_settings_args(p)
    p.add_argument(
        "--sweep",
        action="append",
        metavar="KEY=v1,v2,...",
        help="evaluate the mask mode under each value (repeatable): any --set key (listed "
        "below; the track stage's with --track); --modes names one mask mode (default fusion)",
    )
    p.add_argument(
        "--sweep-mode",
        choices=("oneway", "grid"),
        default="oneway",
        help="oneway: one key at a time around the --preset/flags settings; grid: every "
        "combination",
    )
    p.add_argument("--features", type=count(1), default=KEYPOINTS, help="ORB-SLAM3 ORB features")
    p.add_argument(
        "--no-realtime", action="store_true", help="feed frames as fast as tracking goes"
    )
    p.add_argument(
        "--speed",
        type=number(0, open_low=True),
        default=1.0,
        help="realtime replay speed (0.5: half the frame rate, so the schedule holds on a "
        "loaded machine; the late column counts frames fed behind it)",
    )
    p.add_argument("--threads", type=threads(), default=None, help="model threads")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    add_rerun_arg(p, "every condition's trajectory beside the ground truth (3-D) and its ATE")
    p.set_defaults(run=run)


def parse_modes(text: str | None, have_model: bool, have_masks: bool) -> list[str]:
    """Validated condition names in order (duplicates dropped)."""
    if text is None:
        text = DEFAULT_MODES if have_model else ("raw,gt,oracle,masks" if have_masks else
                                                 "raw,gt,oracle")  # fmt: skip
    names = list(dict.fromkeys(t.strip() for t in text.split(",") if t.strip()))
    valid = (*SPECIAL, *MODES, "masks", *DIAGNOSTIC)
    bad = [n for n in names if n not in valid]
    if bad:
        raise SlimsegError(f"--modes: unknown {', '.join(bad)}; valid: {', '.join(valid)}")
    wants_model = [n for n in names if n in MODES]
    if wants_model and not have_model:
        raise SlimsegError(
            f"--modes {','.join(wants_model)} need --model X.onnx or --gt-instances (or read "
            "masks with --masks)"
        )
    read = [n for n in names if n == "masks" or n in DIAGNOSTIC]
    if read and not have_masks:
        raise SlimsegError(f"--modes {','.join(read)} needs --masks DIR")
    if not names:
        raise SlimsegError("--modes is empty")
    return names


def _restore_list(text: str | None, names: list[str]) -> tuple[str, ...]:
    """Masked conditions to restore: ``all`` of them, or the listed ones (each requested)."""
    masked = [n for n in names if n not in ("raw", "oracle", *DIAGNOSTIC)]
    if text is None:
        return ()
    if text == "all":
        return tuple(masked)
    wanted = [t.strip() for t in text.split(",") if t.strip()]
    bad = [w for w in wanted if w not in masked]
    if bad:
        raise SlimsegError(f"--restore {','.join(bad)}: not among the masked --modes {masked}")
    return tuple(wanted)


def _inputs(args: argparse.Namespace) -> dict:
    """The paths slam-eval reads (``--out`` may neither be nor contain one)."""
    return {"--sequence": args.sequence, "--masks": args.masks, "--model": args.model,
            "--vocab": args.vocab}  # fmt: skip


def run(args: argparse.Namespace) -> int:
    from slimseg.data.bags.poses import ground_truth
    from slimseg.data.sequence_source import open_sequence
    from slimseg.slam import session

    say = (lambda s: print(s, file=sys.stderr)) if args.json else print
    notes: list[str] = []  # said once the inputs have loaded
    masking, track = settings_from_args(args, None if args.gt_instances else args.model, notes)
    dropout = dropout_from_args(args)
    if args.runs < 1:
        raise SlimsegError(f"--runs {args.runs} must be at least 1")
    if not 0 < args.speed <= 10:
        raise SlimsegError(f"--speed {args.speed}: expected a factor in (0, 10]")
    if args.sweep and args.rerun is not None:
        raise SlimsegError("--rerun records one sequence's conditions: drop --sweep to use it")
    if args.sweep:
        from slimseg.cli.slam_sweep import run_sweep_command

        return run_sweep_command(args, masking, say, track, dropout, notes)
    if len(args.sequence) > 1:
        raise SlimsegError("several --sequence values need --sweep (one table per sequence)")
    args.sequence = args.sequence[0]
    names = parse_modes(
        args.modes, args.model is not None or args.gt_instances, args.masks is not None
    )
    rerun = rerun_path(args, Path(args.out), _inputs(args))
    with open_sequence(args.sequence, bag_options_from_args(args)) as seq:
        gt = partial(ground_truth, seq.root, args.groundtruth, args.pose_topic, args.pose_frame)
        session.refuse_masks_inside(args.out, args.masks)
        plan = session.Plan(
            sequence=seq,
            groundtruth=gt,
            names=names,
            model=args.model,
            gt_instances=args.gt_instances,
            masks=args.masks,
            restore=_restore_list(args.restore, names),
            engine=args.engine,
            runs=args.runs,
            vocab=args.vocab,
            masking=masking,
            keypoints=args.keypoints,
            track=track,
            dropout=dropout,
            features=args.features,
            realtime=not args.no_realtime,
            speed=args.speed,
            threads=args.threads,
            progress=not args.quiet,
            rerun=rerun,
        )
        out = args.out
        # every file appears when the session is done, replacing an earlier session's folder
        # whole (never mixed into the new table); a folder holding a user's files is refused
        with staged_dir(out, command="slam-eval", inputs=_inputs(args)) as stage:
            for line in notes:
                print(line, file=sys.stderr)
            rows, info = session.run_plan(plan, stage, say)
    from slimseg.slam.report import as_json_rows, table_lines

    say(f"{info.engine} on {seq.root.name}: {info.frames} frames, vocabulary {info.vocabulary}, "
        f"intrinsics {info.intrinsics}")  # fmt: skip
    say(table_lines(rows, markdown=False))
    say(f"written: {out / 'results.md'}, results.csv, runs.csv, trajectories.png")
    if args.json:
        print(json.dumps(as_json_rows(rows), indent=1))
    if not any(r["scored_runs"] for r in rows[:-1]):
        raise SlimsegError("no condition could be scored (see the status column)")
    return 0
