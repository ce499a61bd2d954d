"""Write ROS recordings with ``rosbags``' own writers: a ROS 1 ``.bag``, a bare ``.mcap`` file, or
a rosbag2 folder with MCAP or SQLite storage (:data:`STORAGES`).

The recording is built in a temporary folder beside ``path`` and renamed into place when the
writer closes cleanly; on an exception nothing is left behind. An existing ``path`` is refused
(as ``rosbag record`` and ``ros2 bag record`` refuse it): a bag is never overwritten.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from slimseg.data.bags.header import CAMERA_INFO, COMPRESSED, IMAGE, POSE, Header, check_stamp
from slimseg.data.bags.mcap_crc import seal
from slimseg.data.bags.reader import require_rosbags
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import publish_new, stage_name

STORAGES = ("mcap", "sqlite3")  # rosbag2 folder storage plugins


def bag_kind(path: str | Path, storage: str | None = None) -> str:
    """``"ros1"`` (``.bag``), ``"mcap"`` (a bare ``.mcap`` file) or ``"rosbag2-<storage>"``
    (any other path, with ``storage`` one of :data:`STORAGES`)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".bag" and storage is None:
        return "ros1"
    if suffix == ".mcap" and storage is None:
        return "mcap"
    if storage not in STORAGES:
        raise SlimsegError(
            f"{path}: a bag output is a .bag or .mcap file, or a rosbag2 folder with a storage "
            f"({', '.join(STORAGES)})"
        )
    return f"rosbag2-{storage}"


class BagWriter:
    """Messages in, a recording out (use as a context manager; see the module docstring).

    Each ``write_*`` takes the topic, the ``Header`` (stamp and ``frame_id``) and the payload;
    the log time is the header stamp."""

    def __init__(self, path: str | Path, storage: str | None = None, option: str = "--out"):
        self.path = Path(path)
        self.kind = bag_kind(self.path, storage)
        self._option = option
        if os.path.lexists(self.path):
            raise SlimsegError(f"{option} {self.path} exists: a bag is never overwritten")
        require_rosbags(self.path)
        from rosbags.typesys import Stores, get_typestore

        self.ros1 = self.kind == "ros1"
        self._store = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stage = self.path.with_name(stage_name(self.path.name))
        self._stage.mkdir()
        self._target = self._stage / self.path.name
        try:
            if self.ros1:
                from rosbags.rosbag1 import Writer

                self._writer = Writer(self._target)
            else:
                from rosbags.rosbag2 import StoragePlugin, Writer

                plugin = (
                    StoragePlugin.SQLITE3 if self.kind.endswith("sqlite3") else StoragePlugin.MCAP
                )
                self._writer = Writer(self._target, version=9, storage_plugin=plugin)
            self._writer.open()
        except BaseException:
            shutil.rmtree(self._stage, ignore_errors=True)
            raise
        self._conns: dict[str, object] = {}
        self._seq: dict[str, int] = {}

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: object, *rest: object) -> None:
        try:
            if exc_type is None:
                self._writer.close()
                made = self._target / f"{self.path.name}.mcap" if self.kind == "mcap" else None
                for mcap in [made] if made else sorted(self._target.glob("*.mcap")):
                    seal(mcap)  # chunk and data-section CRCs, checked when read back
                publish_new(made or self._target, self.path, self._option)
        finally:
            shutil.rmtree(self._stage, ignore_errors=True)

    def _header(self, topic: str, header: Header) -> object:
        types = self._store.types
        sec, nsec = divmod(header.ns, 1_000_000_000)
        stamp = types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        if self.ros1:
            self._seq[topic] = self._seq.get(topic, -1) + 1
            return types["std_msgs/msg/Header"](
                seq=self._seq[topic], stamp=stamp, frame_id=header.frame_id
            )
        return types["std_msgs/msg/Header"](stamp=stamp, frame_id=header.frame_id)

    def _write(
        self, topic: str, msgtype: str, header: Header, msg: object, log_ns: int | None = None
    ) -> None:
        for ns in (header.ns, header.ns if log_ns is None else log_ns):
            check_stamp(ns, "ros1" if self.ros1 else "ros2", f"{self._option} {self.path}")
        if topic not in self._conns:
            self._conns[topic] = self._writer.add_connection(topic, msgtype, typestore=self._store)
        raw = (
            self._store.serialize_ros1(msg, msgtype)
            if self.ros1
            else self._store.serialize_cdr(msg, msgtype)
        )
        self._writer.write(self._conns[topic], header.ns if log_ns is None else log_ns, raw)

    def write_image(
        self,
        topic: str,
        header: Header,
        array: np.ndarray,
        encoding: str,
        log_ns: int | None = None,
    ) -> None:
        """A ``sensor_msgs/Image``: ``array [H, W]`` or ``[H, W, C]`` (uint8, uint16 or
        float32, little-endian) stored as is under ``encoding``; ``log_ns``: the log time when
        it is not the header stamp (a recorder's receive time)."""
        a = np.ascontiguousarray(array)
        h, w = a.shape[:2]
        msg = self._store.types[IMAGE](
            header=self._header(topic, header), height=h, width=w, encoding=encoding,
            is_bigendian=0, step=a.nbytes // h, data=a.reshape(-1).view(np.uint8),
        )  # fmt: skip
        self._write(topic, IMAGE, header, msg, log_ns)

    def write_compressed(self, topic: str, header: Header, data: bytes, fmt: str) -> None:
        """A ``sensor_msgs/CompressedImage`` holding ``data`` under ``format`` ``fmt``."""
        msg = self._store.types[COMPRESSED](
            header=self._header(topic, header), format=fmt,
            data=np.frombuffer(data, np.uint8),
        )  # fmt: skip
        self._write(topic, COMPRESSED, header, msg)

    def write_camera_info(
        self,
        topic: str,
        header: Header,
        size: tuple[int, int],
        k: tuple[float, float, float, float],
        distortion: tuple[str, list[float]] = ("plumb_bob", [0.0] * 5),
    ) -> None:
        """A ``sensor_msgs/CameraInfo``: ``size`` (w, h), ``k`` (fx, fy, cx, cy), the
        distortion model and coefficients."""
        fx, fy, cx, cy = k
        kmat = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], np.float64)
        pmat = np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0], np.float64)
        rmat = np.eye(3).reshape(-1)
        roi = self._store.types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        mats = (np.asarray(distortion[1], np.float64), kmat, rmat, pmat)
        names = ("D", "K", "R", "P") if self.ros1 else ("d", "k", "r", "p")
        msg = self._store.types[CAMERA_INFO](
            header=self._header(topic, header), height=size[1], width=size[0],
            distortion_model=distortion[0], **dict(zip(names, mats, strict=True)),
            binning_x=0, binning_y=0, roi=roi,
        )  # fmt: skip
        self._write(topic, CAMERA_INFO, header, msg)

    def write_pose(self, topic: str, header: Header, t: np.ndarray, q: np.ndarray) -> None:
        """A ``geometry_msgs/PoseStamped``: position ``t [3]`` m, quaternion ``q [4]``
        ``(x, y, z, w)``."""
        types = self._store.types
        pose = types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=t[0], y=t[1], z=t[2]),
            orientation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        msg = types[POSE](header=self._header(topic, header), pose=pose)
        self._write(topic, POSE, header, msg)
