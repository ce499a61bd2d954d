"""``slimseg dynamic``: the SLAM-facing masking logic over a TUM RGB-D sequence."""

from __future__ import annotations

import argparse
import csv
import io
import math
import os
import shutil
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

from slimseg.cli.arg_types import count, threads
from slimseg.cli.bag_args import SEQUENCE_HELP, add_bag_args, bag_options_from_args
from slimseg.cli.commands import COMMAND_HELP
from slimseg.cli.rerun_args import add_rerun_arg, kept_recording, rerun_path
from slimseg.cli.settings_args import add_settings_args, settings_from_args
from slimseg.cli.track_args import add_dropout_arg, dropout_from_args
from slimseg.data.bags.sequence import BagSequence
from slimseg.data.bags.writer import STORAGES
from slimseg.data.frame_source import FrameSource
from slimseg.data.images import decode_file
from slimseg.data.sequence_source import open_sequence
from slimseg.data.tum import mask_name
from slimseg.deploy.calibrated import expectation, is_own
from slimseg.dynamic.annotations import Dropout
from slimseg.dynamic.chain_config import ChainConfig, TrackPlan
from slimseg.dynamic.masking_settings import CALIBRATED, MaskingSettings
from slimseg.dynamic.modes import KEYPOINTS, MAX_KEYPOINTS, MODES, Mode
from slimseg.errors import SlimsegError
from slimseg.sequence.mask_bag import (
    MASK_TOPIC,
    MASKED_TOPIC,
    OBJECTS_TOPIC,
    FrameBoxes,
    frame_boxes,
    write_mask_bag,
    writes_foxglove,
)
from slimseg.sequence.restore_run import (
    REPORT_HEADERS,
    RestoreReport,
    report_rows,
    restore_sequence,
)
from slimseg.sequence.sequence_report import SequenceReport
from slimseg.sequence.sequence_run import run_sequence
from slimseg.utils.atomic import stage_name, staged_dir, write_text
from slimseg.utils.outputs import refuse_inputs
from slimseg.utils.table import format_table

MAX_DILATION_PX = 256  # far wider than any object's edge; a kernel grows as its square


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "dynamic",
        help=COMMAND_HELP["dynamic"],
        description="Run a model and the reference masking logic (Eq. 1/3/4 of the substation "
        "paper, YOLO-SLAM's depth-RANSAC, VTD-SLAM's epipolar check) on a TUM-layout sequence. "
        "Writes masks/<rgb timestamp>.png (255 = dynamic), frames.csv and overlay.png; with "
        "ground-truth dynamic/ masks, prints keypoint precision and recall of every mode. "
        "--restore fills the removed regions from neighbouring frames (PatchMatch) and, with a "
        "true background/ (synthetic sequences), scores it against cv2.inpaint.",
    )
    p.add_argument("--model", help="exported .onnx, or weights .pt/.ckpt")
    p.add_argument(
        "--gt-instances",
        action="store_true",
        help="use the sequence's annotations.json instances instead of a model (synthetic "
        "sequences): evaluates the masking logic and the epipolar check without detector errors",
    )
    add_dropout_arg(p)
    p.add_argument("--sequence", required=True, help=SEQUENCE_HELP)
    add_bag_args(p)
    p.add_argument(
        "--out",
        default="runs/dynamic",
        help="output folder; or a .mcap / .bag file (or a rosbag2 folder with --bag-storage): "
        f"the masks as mono8 images on {MASK_TOPIC} with each frame's header",
    )
    p.add_argument(
        "--bag-storage",
        choices=STORAGES,
        help="write --out as a rosbag2 folder with this storage",
    )
    p.add_argument(
        "--bag-masked-rgb",
        action="store_true",
        help=f"bag output: also the colour frames with dynamic pixels black on {MASKED_TOPIC}",
    )
    add_rerun_arg(p, "every frame: image, depth, class-coloured mask, boxes, keypoints, timing")
    p.add_argument("--mode", default=Mode.FUSION.value, choices=MODES)
    p.add_argument(
        "--keypoints",
        type=count(1, MAX_KEYPOINTS),
        default=KEYPOINTS,
        help="ORB features per frame",
    )
    add_settings_args(p)
    p.add_argument(
        "--fps",
        type=float,
        default=None,
        help="--rate thread: replay rate in frames per second (default: the sequence's "
        "timestamps; 0: as fast as the masking goes)",
    )
    p.add_argument(
        "--epipolar-depth",
        action="store_true",
        help="epipolar modes: with the previous depth, use the PnP reprojection error (sees "
        "motion along epipolar lines) where depth is valid",
    )
    p.add_argument(
        "--no-depth",
        action="store_true",
        help="mask from the colour frames alone, as for an RGB-only camera (no depth cut; "
        "Eq. 4 keeps seg masks covering more than the papers' t_o of their box)",
    )
    p.add_argument(
        "--restore",
        action="store_true",
        help="write restored/rgb/<ts>.png and restored/depth/<ts>.png (uint16, depth scale)",
    )
    p.add_argument(
        "--restore-mask",
        choices=("pred", "gt"),
        default=None,
        help="region to restore: the mode's dynamic mask (pred, default) or the ground-truth "
        "dynamic/ masks (gt, default without --model)",
    )
    p.add_argument(
        "--restore-dilation",
        type=count(0, MAX_DILATION_PX),
        default=2,
        help=f"px added around the removed region (0-{MAX_DILATION_PX})",
    )
    p.add_argument("--threads", type=threads(), default=None)
    p.add_argument(
        "--backend", default="auto", help="auto, onnxruntime, openvino[:bf16|:f16], torch"
    )
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if (args.model is None) == (not args.gt_instances):
        raise SlimsegError("slimseg dynamic: give exactly one of --model PATH or --gt-instances")
    notes: list[str] = []  # said once the model has loaded
    masking, track = settings_from_args(args, None if args.gt_instances else args.model, notes)
    if args.fps is not None and not track.rate.thread:
        raise SlimsegError("--fps sets the real-time replay of --rate thread: add --rate thread")
    if args.fps is not None and not (args.fps >= 0 and math.isfinite(args.fps)):
        raise SlimsegError(f"--fps {args.fps}: expected frames per second >= 0")
    dropout = dropout_from_args(args)
    sequence = Path(args.sequence)
    out = Path(args.out)
    bag_out = _bag_output(args, out)
    rerun = rerun_path(args, out, {"--sequence": args.sequence, "--model": args.model})
    with open_sequence(sequence, bag_options_from_args(args)) as seq:  # before the model loads
        return _run(args, seq, masking, track, dropout, bag_out, rerun, notes)


def _run(
    args: argparse.Namespace,
    seq: FrameSource,
    masking: MaskingSettings,
    track: TrackPlan,
    dropout: Dropout | None,
    bag_out: bool,
    rerun: Path | None,
    notes: list[str],
) -> int:
    """:func:`run` on the opened sequence (closed by the caller); ``notes`` printed on stderr
    once the model has loaded."""
    sequence, out = Path(args.sequence), Path(args.out)
    if isinstance(seq, BagSequence):
        if args.gt_instances:
            raise SlimsegError("--gt-instances reads a synthetic TUM folder's annotations.json; "
                               f"a bag ({sequence}) has none: give --model")  # fmt: skip
        print(seq.describe())
    print(seq.describe_camera())
    if args.gt_instances:
        from slimseg.dynamic.annotations import AnnotationInstances

        predictor = AnnotationInstances(sequence, dropout)
        if dropout is not None:
            print(f"ground-truth dropout {dropout.rate:g} in bursts of {dropout.burst}: "
                  f"{predictor.dropped} instance-frames removed")  # fmt: skip
    else:
        from slimseg.deploy.predictor import Predictor

        predictor = Predictor.from_path(args.model, args.backend, threads=args.threads)
    for line in notes:
        print(line, file=sys.stderr)
    restore_mask = args.restore_mask or ("pred" if args.model else "gt")
    if args.restore and restore_mask == "gt" and not (sequence / "dynamic").is_dir():
        raise SlimsegError(
            f"--restore-mask gt needs ground-truth masks in {sequence / 'dynamic'}; "
            "use --restore-mask pred"
        )
    names = list(predictor.names)
    boxes: list[FrameBoxes] | None = None
    observers = []
    if bag_out and writes_foxglove(seq, out, args.bag_storage):
        boxes = []
        observers.append(lambda f, rgb, depth: boxes.append(frame_boxes(f.objects, names)))
    viz = None
    if rerun is not None:
        from slimseg.sequence.rerun_frames import RerunFrames

        truth = seq.root / "dynamic"  # a synthetic sequence's ground-truth masks, if any
        viz = RerunFrames(rerun, names, "slimseg dynamic", truth if truth.is_dir() else None)
        observers.append(viz)
    # the outputs complete or not at all; the recording kept only if they are
    with kept_recording(viz) as seal_rerun, _staged_output(out, seq, bag_out, args, boxes) as stage:
        config = ChainConfig(mode=args.mode, masking=masking, track=track,
                             keypoints=args.keypoints, camera=seq.camera.pinhole,
                             epipolar_depth=args.epipolar_depth,
                             expect=None if args.gt_instances else
                             expectation(predictor.metadata, masking))  # fmt: skip
        report = run_sequence(predictor, seq, stage, config, progress=not args.quiet,
                              replay_fps=args.fps, observers=observers,
                              use_depth=not args.no_depth)  # fmt: skip
        restored = _restore(args, seq, stage, restore_mask) if args.restore else None
        seal_rerun()  # the recording finished before --out is published
    timing = ", ".join(f"{k} {v:.1f} ms" for k, v in report.ms_per_frame.items())
    where = f"bag {out} on {MASK_TOPIC}" if bag_out else out / "masks"
    if boxes is not None:
        where = f"{where} (foxglove.RawImage), objects on {OBJECTS_TOPIC} (ImageAnnotations)"
    print(f"{report.frames} frames, mode {args.mode}: masks in {where}; per frame {timing}")
    described = masking.describe()
    if not args.gt_instances and is_own(predictor.metadata, masking):
        described = (
            f"{CALIBRATED} preset of {Path(args.model).name} " + described[described.index("(") :]
        )
    print(f"masking settings: {described}")
    print(
        f"masking rule ({masking.rule}): {report.dropped} candidate masks left out over "
        f"{report.frames} frames; a mover scoring >= {masking.keep_score:g} left out in "
        f"{report.dropped_confident_frames} frames; the frame given up in {report.gave_up}"
    )
    if track.on:
        total = report.ms_per_frame["model"] + report.ms_per_frame["masking_logic"]
        print(f"track stage: {track.describe()}; model on {report.model_frames} of "
              f"{report.frames} frames, {report.coasted} predicted masks emitted; {total:.1f} "
              f"ms per frame in all (model + masking logic)"
              + ("" if bag_out else f"; {out / 'tracks.csv'}"))  # fmt: skip
        parts = ", ".join(f"{k} {v:.2f}" for k, v in report.stage_parts_ms.items())
        print(f"track stage per frame by part (ms): {parts}")
    _print_latency(report, track.rate.thread)
    _print_scores(report)
    _print_recall_loss(report)
    if report.skipped:
        print(f"{len(report.skipped)} frame(s) without ground truth, e.g. {report.skipped[0]}")
    if restored is not None:
        _print_restored(restored, out, restore_mask)
    return 0


def _print_latency(report: SequenceReport, live: bool) -> None:
    """Per-frame latency as a SLAM front end sees it, and the model results' lag."""
    lat = np.asarray(report.latency_ms)
    if not len(lat):
        return
    where = "model on its own thread" if live else "model inline"
    print(f"latency per frame ({where}): median {np.median(lat):.1f} ms, p95 "
          f"{np.percentile(lat, 95):.1f}, max {lat.max():.1f}; model {report.model_ms_per_run:.1f} "
          f"ms per run")  # fmt: skip
    if live and report.late_ms:
        late = np.asarray(report.late_ms)
        print(f"replay kept up with {int((late < 1).sum())} of {len(late)} frames (taken up "
              f"late by up to {late.max():.0f} ms: reading and writing frames cost the replay "
              f"time a runtime does not spend)")  # fmt: skip
    if live and report.model_lags:
        lags = np.asarray(report.model_lags)
        print(f"model results used: {len(lags)} for {report.frames} frames, lag median "
              f"{np.median(lags):g} frames (max {lags.max()})")  # fmt: skip


def _print_scores(report: SequenceReport) -> None:
    if report.scores:
        rows = [
            [m, s.tp, s.fp, s.fn, _pct(s.precision), _pct(s.recall)]
            for m, s in report.scores.items()
            if s.tp + s.fp + s.fn + s.tn
        ]
        print("dynamic keypoints vs ground truth:")
        print(format_table(["mode", "TP", "FP", "FN", "precision %", "recall %"], rows))
    if report.epipolar:
        print("epipolar check of ground-truth instances (truth as decision):")
        rows = [[k, v] for k, v in sorted(report.epipolar.items())]
        print(format_table(["instances", "count"], rows))


def _print_recall_loss(report: SequenceReport) -> None:
    if report.recall_loss is None:
        return
    s = report.recall_loss.summary()
    hist = ", ".join(f"{k}: {v}" for k, v in s["dropout_histogram"].items()) or "none"
    print(
        f"where recall is lost: {s['missed_dynamic_keypoints']} missed "
        f"dynamic keypoints, {_num(s['missed_on_dropouts_pct'])} % on walkers the mask misses "
        f"entirely in that frame (< 20 % covered), {_num(s['missed_on_partial_pct'])} % on "
        f"walkers covered in part; dropouts in {_num(s['dropout_frames_pct'])} % of moving "
        f"instance-frames, run lengths {{{hist}}}; ghosts (false dynamic keypoints on coasted "
        f"masks only) {_num(s['ghost_pct'])} % of dynamic keypoints"
    )
    if report.precision_loss is not None:
        print(f"where precision is lost: {report.precision_loss.describe()}")


def _num(v: float) -> str:
    return "-" if math.isnan(v) else f"{v:.1f}"


def _bag_output(args: argparse.Namespace, out: Path) -> bool:
    """Whether ``--out`` is a bag; refuses what a bag output cannot hold before any work."""
    if not (args.bag_storage or out.suffix.lower() in (".mcap", ".bag")):
        if args.bag_masked_rgb:
            raise SlimsegError("--bag-masked-rgb needs a bag --out (.mcap, .bag or --bag-storage)")
        return False
    if args.restore:
        raise SlimsegError(f"--restore writes image folders: give --out DIR, not the bag {out}")
    if os.path.lexists(out):
        raise SlimsegError(f"--out {out} exists: a bag is never overwritten; give a new path")
    return True


@contextmanager
def _staged_output(
    out: Path,
    seq: FrameSource,
    bag_out: bool,
    args: argparse.Namespace,
    boxes: list[FrameBoxes] | None = None,
) -> Iterator[Path]:
    """A staging folder for the run's files; on a clean exit they move into the ``out``
    folder, or, for a bag ``out``, the masks are written into the bag (the rest dropped).
    Neither may be or hold an input; a folder ``out`` only replaces slimseg's own."""
    inputs = {"--sequence": args.sequence, "--model": args.model}
    if not bag_out:
        with staged_dir(out, command="dynamic", inputs=inputs) as stage:
            yield stage
        return
    refuse_inputs(out, "--out", inputs)
    created = [p for p in (out.parent, *out.parent.parents) if not p.exists()]
    out.parent.mkdir(parents=True, exist_ok=True)
    work = out.parent / stage_name(out.name)
    work.mkdir()
    try:
        yield work
        write_mask_bag(seq, work / "masks", out, args.bag_storage, args.bag_masked_rgb, boxes)
    finally:
        shutil.rmtree(work, ignore_errors=True)
        for p in created:  # innermost first; only folders this run made and left empty
            if p.is_dir() and not out.exists() and not any(p.iterdir()):
                p.rmdir()


def _restore(args: argparse.Namespace, seq: FrameSource, out: Path, which: str) -> RestoreReport:
    """Restore the frames into ``out/restored`` (``out``: the staging folder, holding this
    run's ``masks/``); with a true background, the score table in ``out/restoration.csv``."""
    folder = out / "masks" if which == "pred" else seq.root / "dynamic"

    def masks(i: int, stamp: float) -> np.ndarray:
        path = folder / mask_name(stamp)
        m = decode_file(path, cv2.IMREAD_GRAYSCALE)
        if m is None:
            raise SlimsegError(f"missing or unreadable dynamic mask {path}")
        return m

    rep = restore_sequence(
        seq,
        masks,
        out,
        args.restore_dilation,
        keypoints=args.keypoints,
        progress=not args.quiet,
    )
    if rep.methods:
        buf = io.StringIO()
        writer = csv.writer(buf)
        writer.writerow(REPORT_HEADERS)
        writer.writerows(report_rows(rep))
        write_text(out / "restoration.csv", buf.getvalue())
    return rep


def _print_restored(rep: RestoreReport, out: Path, which: str) -> None:
    cover = 100 * float(np.mean(rep.coverage)) if rep.coverage else float("nan")
    print(
        f"restored {rep.restored} of {rep.frames} frames ({which} masks) into "
        f"{out / 'restored'}; {rep.references / max(rep.restored, 1):.1f} references per "
        f"frame, {_pct(cover / 100)} % of removed pixels seen by a reference"
    )
    if rep.methods:
        print(f"restoration inside the removed regions vs true background ({rep.scored} frames):")
        print(format_table(REPORT_HEADERS, report_rows(rep)))
        print(f"table written to {out / 'restoration.csv'}")


def _pct(v: float) -> str:
    return "-" if math.isnan(v) else f"{100 * v:.1f}"
