"""``slimseg data bag2tum`` and ``slimseg data tum2bag``: ROS recordings to the TUM layout and
back (docs/bags.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from slimseg.cli.bag_args import add_bag_args, bag_options_from_args
from slimseg.data.bags.from_tum import COLOURS, DEPTHS
from slimseg.data.bags.writer import STORAGES
from slimseg.utils.extras import install_command


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Register ``bag2tum`` and ``tum2bag`` on ``sub``."""
    p = sub.add_parser(
        "bag2tum",
        help="convert a ROS bag (.bag, .mcap, rosbag2 folder) to a TUM RGB-D folder",
        description="Read a ROS 1 bag, a rosbag2 folder (MCAP or SQLite) or a bare .mcap and "
        "write the paired colour and depth frames in the TUM layout: rgb/ and depth/ PNGs "
        "(depth 16-bit at 5000 per metre), rgb.txt, depth.txt, camera.yaml and, with "
        f"--pose-topic, groundtruth.txt. Needs {install_command('ros')}.",
    )
    p.add_argument("--bag", type=Path, required=True, help="the recording")
    p.add_argument("--out", type=Path, required=True, help="TUM folder to write")
    add_bag_args(p)
    p.add_argument("--pose-topic", help="PoseStamped / Odometry / tf topic → groundtruth.txt")
    p.add_argument("--pose-frame", help="with a tf --pose-topic: the child frame to use")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run_bag2tum)
    q = sub.add_parser(
        "tum2bag",
        help="write a TUM RGB-D folder as a ROS bag (.bag, .mcap or rosbag2 folder)",
        description="Write a TUM-layout sequence as a ROS recording on the TUM bags' topics "
        "(/camera/rgb/image_color, /camera/depth/image, /camera/rgb/camera_info), each "
        f"message stamped with its file's timestamp. Needs {install_command('ros')}.",
    )
    q.add_argument("--sequence", type=Path, required=True, help="TUM-layout folder")
    q.add_argument("--out", type=Path, required=True, help=".bag, .mcap, or a rosbag2 folder")
    q.add_argument("--bag-storage", choices=STORAGES, help="write --out as a rosbag2 folder")
    q.add_argument("--colour", choices=COLOURS, default="rgb8", help="Image encoding or JPEG/PNG")
    q.add_argument(
        "--depth", choices=DEPTHS, default="16UC1", help="16UC1 (mm), 32FC1 (m) or compressedDepth"
    )
    q.set_defaults(run=run_tum2bag)


def run_bag2tum(args: argparse.Namespace) -> int:
    from slimseg.data.bags.to_tum import bag_to_tum

    rep = bag_to_tum(
        args.bag,
        args.out,
        bag_options_from_args(args),
        pose_topic=args.pose_topic,
        pose_frame=args.pose_frame,
        progress=not args.quiet,
    )
    gt = f", {rep.poses} poses in groundtruth.txt" if args.pose_topic else ""
    print(f"{rep.frames} frame pairs written to {args.out} ({rep.unmatched_rgb} colour and "
          f"{rep.unmatched_depth} depth messages without a partner{gt})")  # fmt: skip
    return 0


def run_tum2bag(args: argparse.Namespace) -> int:
    from slimseg.data.bags.from_tum import tum_to_bag

    n = tum_to_bag(args.sequence, args.out, args.bag_storage, args.colour, args.depth)
    print(f"{n} frames written to {args.out}")
    return 0
