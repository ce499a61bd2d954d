"""Options for reading a ROS bag as a sequence, shared by every command that takes
``--sequence`` (see docs/bags.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from slimseg.data.bags.sequence import BagOptions

SEQUENCE_HELP = (
    "TUM-layout folder (rgb.txt, depth.txt), or a ROS recording: a ROS 1 .bag, a rosbag2 "
    "folder (MCAP or SQLite) or a bare .mcap file (needs slimseg[ros])"
)


def add_bag_args(p: argparse.ArgumentParser) -> None:
    """``--rgb-topic``, ``--depth-topic``, ``--camera-info-topic``, ``--camera``."""
    g = p.add_argument_group("ROS bag as the sequence (docs/bags.md)")
    g.add_argument("--rgb-topic", help="colour topic (default: the bag's only colour topic)")
    g.add_argument("--depth-topic", help="depth topic (default: the only topic named *depth*)")
    g.add_argument(
        "--camera-info-topic",
        help="camera_info topic for the intrinsics (default: the only one, or the one beside "
        "the colour topic)",
    )
    g.add_argument(
        "--camera",
        type=Path,
        help="camera.yaml (fx, fy, cx, cy) for a bag without camera_info",
    )


def bag_options_from_args(args: argparse.Namespace) -> BagOptions:
    """The :class:`BagOptions` the parsed arguments give."""
    return BagOptions(
        rgb_topic=args.rgb_topic,
        depth_topic=args.depth_topic,
        camera_info_topic=args.camera_info_topic,
        camera=args.camera,
    )
