"""A TUM-layout sequence written as a ROS recording (``slimseg data tum2bag``): the way back of
``slimseg data bag2tum``, and how the tests and the benchmark make bags of every kind.

Topics follow the TUM RGB-D benchmark's own bags: colour on ``/camera/rgb/image_color``,
depth on ``/camera/depth/image``, intrinsics on ``/camera/rgb/camera_info`` (one per colour
frame); compressed colour adds ``/compressed``, compressed depth ``/compressedDepth``; a
``groundtruth.txt`` goes on :data:`POSE_TOPIC` as ``geometry_msgs/PoseStamped`` in
:data:`WORLD_FRAME`. Each message is stamped (header and log time) with its file's timestamp and
written in time order; frames stream one at a time.
"""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np

from slimseg.data.bags.header import Header, stamp_ns
from slimseg.data.bags.writer import BagWriter
from slimseg.data.tum import TumSequence, read_trajectory
from slimseg.errors import SlimsegError

RGB_TOPIC = "/camera/rgb/image_color"
DEPTH_TOPIC = "/camera/depth/image"
INFO_TOPIC = "/camera/rgb/camera_info"
FRAME_ID = "camera_rgb_optical_frame"
POSE_TOPIC = "/groundtruth"
WORLD_FRAME = "world"
COLOURS = ("rgb8", "bgr8", "jpeg", "png")  # Image encodings, or CompressedImage formats
DEPTHS = ("16UC1", "32FC1", "compressedDepth")  # Image encodings, or the PNG transport
MM_PER_M = 1000.0


def tum_to_bag(
    sequence: str | Path,
    out: str | Path,
    storage: str | None = None,
    colour: str = "rgb8",
    depth: str = "32FC1",
    camera_info: bool = True,
) -> int:
    """Write ``sequence`` (a TUM folder) as the bag ``out`` (``.bag``, ``.mcap``, or a rosbag2
    folder with ``storage``); ``colour`` one of :data:`COLOURS`, ``depth`` one of
    :data:`DEPTHS` (``16UC1``/``compressedDepth``: millimetres; ``32FC1``: metres, NaN = no
    depth). Returns the number of frames written."""
    if colour not in COLOURS:
        raise SlimsegError(f"--colour {colour}: expected one of {', '.join(COLOURS)}")
    if depth not in DEPTHS:
        raise SlimsegError(f"--depth {depth}: expected one of {', '.join(DEPTHS)}")
    with TumSequence(sequence) as seq:
        cam = seq.camera
        gt_path = seq.root / "groundtruth.txt"
        poses = read_trajectory(gt_path) if gt_path.is_file() else np.zeros((0, 8))
        k = 0
        with BagWriter(out, storage) as bag:
            for i in range(len(seq)):
                rgb, depth_m, t = seq.load(i)
                t_depth = seq.frames[i][1][0]
                while k < len(poses) and poses[k, 0] <= t:  # time order: the poses up to now
                    row = poses[k]
                    bag.write_pose(
                        POSE_TOPIC, Header(stamp_ns(row[0]), WORLD_FRAME), row[1:4], row[4:]
                    )
                    k += 1
                head = Header(stamp_ns(t), FRAME_ID)
                if camera_info:
                    size = (rgb.shape[1], rgb.shape[0])
                    bag.write_camera_info(INFO_TOPIC, head, size, cam.pinhole)
                _write_colour(bag, head, rgb, colour)
                _write_depth(bag, Header(stamp_ns(t_depth), FRAME_ID), depth_m, depth)
            for row in poses[k:]:
                bag.write_pose(POSE_TOPIC, Header(stamp_ns(row[0]), WORLD_FRAME), row[1:4], row[4:])
        return len(seq)


def _write_colour(bag: BagWriter, head: Header, rgb: np.ndarray, colour: str) -> None:
    if colour == "rgb8":
        bag.write_image(RGB_TOPIC, head, rgb, "rgb8")
    elif colour == "bgr8":
        bag.write_image(RGB_TOPIC, head, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), "bgr8")
    else:
        ok, buf = cv2.imencode(f".{'jpg' if colour == 'jpeg' else 'png'}",
                               cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))  # fmt: skip
        assert ok, "cv2 encodes any uint8 image"
        bag.write_compressed(f"{RGB_TOPIC}/compressed", head, buf.tobytes(), colour)


def _write_depth(bag: BagWriter, head: Header, depth_m: np.ndarray, depth: str) -> None:
    if depth == "32FC1":
        bag.write_image(DEPTH_TOPIC, head, np.where(depth_m > 0, depth_m, np.nan), "32FC1")
        return
    mm = np.clip(np.round(depth_m * MM_PER_M), 0, 65535).astype(np.uint16)
    if depth == "16UC1":
        bag.write_image(DEPTH_TOPIC, head, mm, "16UC1")
        return
    ok, png = cv2.imencode(".png", mm)
    assert ok, "cv2 encodes any uint16 image"
    data = struct.pack("<iff", 0, 0.0, 0.0) + png.tobytes()
    bag.write_compressed(f"{DEPTH_TOPIC}/compressedDepth", head, data, "16UC1; compressedDepth png")
