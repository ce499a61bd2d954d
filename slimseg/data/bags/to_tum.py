"""``slimseg data bag2tum``: a ROS recording converted to the TUM RGB-D layout, for tools that
want folders.

Writes ``rgb/<stamp>.png`` (8-bit colour), ``depth/<stamp>.png`` (16-bit, 5000 units per metre,
0 = no depth), ``rgb.txt`` and ``depth.txt`` (the paired frames, stamps with 6 decimals),
``camera.yaml`` (fx, fy, cx, cy, depth_scale, width, height) and, given a pose topic,
``groundtruth.txt``. Frames stream one at a time; the folder appears complete or not at all.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from slimseg.data.bags.poses import read_poses
from slimseg.data.bags.sequence import BagOptions, BagSequence
from slimseg.data.tum import TUM_DEPTH_SCALE, write_trajectory
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import staged_dir, write_png, write_text, write_yaml

_HEADER = "# {what}\n# file: '{name}' (slimseg data bag2tum)\n# timestamp filename\n"


@dataclass
class Bag2TumReport:
    """What was written: frames, colour/depth messages without a partner, poses."""

    frames: int
    unmatched_rgb: int
    unmatched_depth: int
    poses: int = 0


def bag_to_tum(
    bag: str | Path,
    out: str | Path,
    options: BagOptions | None = None,
    pose_topic: str | None = None,
    pose_frame: str | None = None,
    progress: bool = False,
) -> Bag2TumReport:
    """Convert ``bag`` into the TUM folder ``out`` (see the module docstring); ``pose_topic``:
    a ``PoseStamped`` / ``Odometry`` / ``tf`` topic (``pose_frame``: the tf child frame)
    written as ``groundtruth.txt``."""
    if pose_frame is not None and pose_topic is None:
        raise SlimsegError("--pose-frame chooses a tf child frame: give --pose-topic too")
    with BagSequence(bag, options or BagOptions()) as seq:
        poses = read_poses(seq.root, pose_topic, pose_frame) if pose_topic else None
        rgb_lines, depth_lines = [], []
        with staged_dir(Path(out), "--out", "data bag2tum", {"--bag": bag}) as stage:
            for i in tqdm(range(len(seq)), desc="bag2tum", disable=not progress):
                rgb, depth, t = seq.load(i)
                (_, rgb_name), (t_depth, depth_name) = seq.frames[i]
                write_png(stage / rgb_name, rgb)
                raw = np.clip(np.round(depth * TUM_DEPTH_SCALE), 0, 65535).astype(np.uint16)
                write_png(stage / depth_name, raw)
                rgb_lines.append(f"{t:.6f} {rgb_name}\n")
                depth_lines.append(f"{t_depth:.6f} {depth_name}\n")
                if i == 0:
                    c = seq.camera
                    h, w = rgb.shape[:2]
                    write_yaml(stage / "camera.yaml", {
                        "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
                        "depth_scale": TUM_DEPTH_SCALE, "width": w, "height": h,
                    })  # fmt: skip
            name = Path(bag).name
            write_text(
                stage / "rgb.txt",
                _HEADER.format(what="color images", name=name) + "".join(rgb_lines),
            )
            write_text(
                stage / "depth.txt",
                _HEADER.format(what="depth maps", name=name) + "".join(depth_lines),
            )
            if poses is not None:
                write_trajectory(stage / "groundtruth.txt", poses)
    f = seq.frames
    return Bag2TumReport(
        len(f), f.unmatched_rgb, f.unmatched_depth, 0 if poses is None else len(poses)
    )
