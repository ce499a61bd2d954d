"""``slimseg data synth``: write the embedded procedural RGB-D dataset (no download)."""

from __future__ import annotations

import argparse
from pathlib import Path

from slimseg.cli.arg_types import count, number
from slimseg.data.synth.presets import PRESETS


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the ``synth`` subcommand on ``sub`` (sets ``run``)."""
    p = sub.add_parser(
        "synth",
        help="generate the embedded synthetic RGB-D instance-segmentation dataset",
        description="Render a procedural dataset from a seed: square images with 1-8 "
        "instances of person, dog, sports ball, bottle, chair and tv on textured, cluttered "
        "rooms, exact visible-part masks as COCO RLE json, TUM depth (uint16, 5000 = 1 m) and "
        "a data.yaml for 'slimseg train --data'. With --sequences, also TUM RGB-D sequences "
        "(moving camera, walking people) with dynamic masks and true static backgrounds. "
        "The same arguments give byte-identical files.",
    )
    p.add_argument("--out", type=Path, required=True, help="output folder (created)")
    p.add_argument(
        "--train",
        type=count(0),
        default=512,
        help="training images (default 512); 0 with --val 0 and --sequences N: sequences only",
    )
    p.add_argument("--val", type=count(0), default=128, help="validation images (default 128)")
    p.add_argument(
        "--imgsz", type=int, default=320, help="image size, square, multiple of 32 (default 320)"
    )
    p.add_argument("--seed", type=count(0), default=0, help="random seed (default 0)")
    p.add_argument(
        "--sequences", type=count(0), default=0, help="TUM-style RGB-D sequences (default 0)"
    )
    p.add_argument(
        "--frames", type=count(1), default=60, help="frames per sequence at 30 Hz (default 60)"
    )
    p.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        default=None,
        help="sequences modelled on TUM fr3: walking_xyz (camera moves tens of cm along x/y/z), "
        "walking_static, walking_halfsphere, sitting_static, walking_rpy (camera turns fast "
        "about roll, pitch and yaw, peaks of 60-80 deg/s, at one spot); 2-3 people close to the "
        "camera (default: the small-motion sequences)",
    )
    p.add_argument(
        "--exposure-ms",
        type=number(0),
        default=None,
        metavar="MS",
        help="shutter time of the sequences' motion blur in milliseconds, 0 to 33.3: camera "
        "and walker motion during the exposure blurs the RGB frames (rgb/, background/rgb/); "
        "depth, dynamic/ masks and annotations stay sharp. 0 = no blur. Default: the "
        "preset's, 20 for walking_rpy, 0 for the others and the default sequences",
    )
    p.add_argument(
        "--seq-size",
        type=count(1),
        nargs=2,
        default=(640, 480),
        metavar=("W", "H"),
        help="sequence frame size (TUM: 640 480)",
    )
    w = p.add_argument_group(
        "training frames from the sequence world (640x480 rooms, people walking close to "
        "the camera: what slimseg dynamic and slam-eval mask)"
    )
    w.add_argument(
        "--seq-train",
        type=count(0),
        default=0,
        metavar="N",
        help="training worlds: short sequences, presets mixed, written under "
        "train_sequences/ with annotations.json and listed as the train split's 'sequences' "
        "(beside --train images, if any); their seeds never meet an evaluation sequence's",
    )
    w.add_argument("--seq-val", type=count(0), default=0, metavar="N", help="validation worlds")
    w.add_argument(
        "--seq-frames",
        type=count(1),
        default=96,
        help="frames each world spans at 30 Hz (default 96)",
    )
    w.add_argument(
        "--seq-step",
        type=count(1),
        default=6,
        help="write every N-th of them (default 6: 16 frames per world, 0.2 s apart)",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace a previous dataset in --out (deletes only what its manifest "
        ".slimseg-outputs.json lists; a folder holding anything else is refused)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Generate the dataset described by ``args``; print a one-line summary. Bad arguments
    raise ``SlimsegError``."""
    from slimseg.data.synth import generate
    from slimseg.data.synth.world_frames import WorldSplits

    report = generate(
        args.out,
        args.train,
        args.val,
        args.imgsz,
        args.seed,
        args.sequences,
        args.frames,
        seq_size=tuple(args.seq_size),
        overwrite=args.overwrite,
        progress=not args.quiet,
        preset=args.preset,
        exposure_ms=args.exposure_ms,
        worlds=WorldSplits(args.seq_train, args.seq_val, args.seq_frames, args.seq_step),
    )
    print(report.summary())
    return 0
