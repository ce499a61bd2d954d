"""Recordings of a TUM folder written by the tooling robots record with, not by the library slimseg
reads with: an MCAP of the ``ros1`` profile (``mcap-ros1-support``'s writer, what ``mcap
convert`` makes of a ROS 1 bag), one of the ``ros2`` profile (``mcap-ros2-support``), Foxglove
protobuf MCAPs (``foxglove-sdk``, as robots without ROS log; ``mcap-protobuf-support`` with
``foxglove-schemas-protobuf``, as older pipelines do) and a Foxglove JSON-schema MCAP (the
``mcap`` package's plain ``Writer``).

Topics are a RealSense driver's (:data:`RGB`, :data:`DEPTH`, :data:`INFO`); each message is
logged :data:`LOG_DELAY_NS` after its header stamp and every depth message one frame late (after
the next colour frame), as a recorder on a busy machine logs them.
"""

from __future__ import annotations

import base64
import json
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from slimseg.data.bags.header import stamp_ns
from slimseg.data.tum import TumSequence, read_trajectory

RGB = "/camera/camera/color/image_raw"
DEPTH = "/camera/camera/aligned_depth_to_color/image_raw"
INFO = "/camera/camera/color/camera_info"
GT = "/mocap/pose"
TF = "/tf"
FRAME = "camera_color_optical_frame"
LOG_DELAY_NS = 30_000_000


def _frames(seq_dir: Path) -> Iterator[tuple[int, int, int, np.ndarray, np.ndarray, np.ndarray]]:
    """``(colour stamp ns, depth stamp ns, depth log time ns, rgb, depth mm uint16, depth m)``
    (the folder's depth is on whole millimetres)."""
    seq = TumSequence(seq_dir)
    period = int(1e9 / seq.fps)
    for i in range(len(seq)):
        rgb, depth_m, t = seq.load(i)
        td = stamp_ns(seq.frames[i][1][0])
        mm = np.round(depth_m * 1000).astype(np.uint16)
        yield stamp_ns(t), td, td + LOG_DELAY_NS + period, rgb, mm, depth_m


def _k(seq_dir: Path) -> list[float]:
    c = TumSequence(seq_dir).camera
    return [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0]


def _poses(seq_dir: Path) -> np.ndarray:
    return read_trajectory(seq_dir / "groundtruth.txt")


def _in_log_order(items: list[tuple[int, str, object]]) -> list[tuple[int, str, object]]:
    return sorted(items, key=lambda x: x[0])


def write_ros1_mcap(seq_dir: Path, out: Path) -> None:
    """``ros1`` profile: rgb8 colour, 16UC1 depth, CameraInfo, PoseStamped ground truth."""
    from mcap_ros1._vendor.genpy import dynamic
    from mcap_ros1._vendor.genpy.rostime import Time
    from mcap_ros1.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)

    def classes(name: str) -> dict:
        text, _ = store.generate_msgdef(name.replace("/", "/msg/"), ros_version=1)
        return dynamic.generate_dynamic(name, text)

    img, info, pose = (
        classes("sensor_msgs/Image"),
        classes("sensor_msgs/CameraInfo"),
        classes("geometry_msgs/PoseStamped"),
    )

    def header(cls: dict, ns: int, frame: str) -> object:
        return cls["std_msgs/Header"](0, Time(ns // 10**9, ns % 10**9), frame)

    items = []
    k = _k(seq_dir)
    for t, td, log_d, rgb, mm, _ in _frames(seq_dir):
        h, w = mm.shape
        items.append((t + LOG_DELAY_NS, INFO, info["sensor_msgs/CameraInfo"](
            header=header(info, t, FRAME), height=h, width=w, distortion_model="plumb_bob",
            D=[0.0] * 5, K=k, R=[1.0, 0, 0, 0, 1, 0, 0, 0, 1], P=[*k[:3], 0, *k[3:6], 0, 0, 0,
            1, 0]
        )))  # fmt: skip
        items.append((t + LOG_DELAY_NS, RGB, img["sensor_msgs/Image"](
            header=header(img, t, FRAME), height=h, width=w, encoding="rgb8", is_bigendian=0,
            step=3 * w, data=rgb.tobytes(),
        )))  # fmt: skip
        items.append((log_d, DEPTH, img["sensor_msgs/Image"](
            header=header(img, td, FRAME), height=h, width=w, encoding="16UC1", is_bigendian=0,
            step=2 * w, data=mm.astype("<u2").tobytes(),
        )))  # fmt: skip
    P = pose["geometry_msgs/PoseStamped"]
    for row in _poses(seq_dir):
        msg = P(header=header(pose, stamp_ns(row[0]), "world"))
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = row[1:4]
        q = msg.pose.orientation
        q.x, q.y, q.z, q.w = row[4:]
        items.append((stamp_ns(row[0]), GT, msg))
    with out.open("wb") as f:
        writer = Writer(f)
        for log, topic, msg in _in_log_order(items):
            writer.write_message(topic, msg, log_time=log, publish_time=log)
        writer.finish()


def write_ros2_mcap(seq_dir: Path, out: Path) -> None:
    """``ros2`` profile through ``mcap-ros2-support``: rgb8 colour, 16UC1 depth, CameraInfo,
    PoseStamped ground truth (messages as dicts, schemas from rosbags' ROS 2 definitions)."""
    from mcap_ros2.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)

    def header(ns: int, frame: str) -> dict:
        return {"stamp": {"sec": ns // 10**9, "nanosec": ns % 10**9}, "frame_id": frame}

    items = []
    k = _k(seq_dir)
    for t, td, log_d, rgb, mm, _ in _frames(seq_dir):
        h, w = mm.shape
        items.append((t + LOG_DELAY_NS, INFO, {
            "header": header(t, FRAME), "height": h, "width": w, "distortion_model": "plumb_bob",
            "d": [0.0] * 5, "k": k, "r": [1.0, 0, 0, 0, 1, 0, 0, 0, 1],
            "p": [*k[:3], 0, *k[3:6], 0, 0, 0, 1, 0],
        }))  # fmt: skip
        items.append((t + LOG_DELAY_NS, RGB, {
            "header": header(t, FRAME), "height": h, "width": w, "encoding": "rgb8",
            "is_bigendian": 0, "step": 3 * w, "data": rgb.tobytes(),
        }))  # fmt: skip
        items.append((log_d, DEPTH, {
            "header": header(td, FRAME), "height": h, "width": w, "encoding": "16UC1",
            "is_bigendian": 0, "step": 2 * w, "data": mm.astype("<u2").tobytes(),
        }))  # fmt: skip
    for row in _poses(seq_dir):
        pose = {"position": dict(zip("xyz", row[1:4], strict=True)),
                "orientation": dict(zip("xyzw", row[4:], strict=True))}  # fmt: skip
        items.append((stamp_ns(row[0]), GT, {"header": header(stamp_ns(row[0]), "world"),
                                             "pose": pose}))  # fmt: skip
    types = {RGB: "sensor_msgs/msg/Image", DEPTH: "sensor_msgs/msg/Image",
             INFO: "sensor_msgs/msg/CameraInfo", GT: "geometry_msgs/msg/PoseStamped"}  # fmt: skip
    with out.open("wb") as f:
        writer = Writer(f)
        schemas = {}
        for name in set(types.values()):
            text, _ = store.generate_msgdef(name, ros_version=2)
            schemas[name] = writer.register_msgdef(name, text)
        for log, topic, msg in _in_log_order(items):
            writer.write_message(topic, schemas[types[topic]], msg, log_time=log, publish_time=log)
        writer.finish()


def write_foxglove_sdk(seq_dir: Path, out: Path) -> None:
    """Protobuf through ``foxglove-sdk``: RawImage rgb8 colour and 16UC1 depth,
    CameraCalibration, PoseInFrame ground truth."""
    import foxglove
    from foxglove.channels import CameraCalibrationChannel, PoseInFrameChannel, RawImageChannel
    from foxglove.messages import (
        CameraCalibration,
        Pose,
        PoseInFrame,
        Quaternion,
        RawImage,
        Timestamp,
        Vector3,
    )

    def ts(ns: int) -> Timestamp:
        return Timestamp(sec=ns // 10**9, nsec=ns % 10**9)

    ctx = foxglove.Context()
    chans = {
        RGB: RawImageChannel(RGB, context=ctx),
        DEPTH: RawImageChannel(DEPTH, context=ctx),
        INFO: CameraCalibrationChannel(INFO, context=ctx),
        GT: PoseInFrameChannel(GT, context=ctx),
    }
    items = []
    k = _k(seq_dir)
    for t, td, log_d, rgb, mm, _ in _frames(seq_dir):
        h, w = mm.shape
        items.append((t + LOG_DELAY_NS, INFO, CameraCalibration(
            timestamp=ts(t), frame_id=FRAME, width=w, height=h, distortion_model="plumb_bob",
            D=[0.0] * 5, K=k,
        )))  # fmt: skip
        items.append((t + LOG_DELAY_NS, RGB, RawImage(
            timestamp=ts(t), frame_id=FRAME, width=w, height=h, encoding="rgb8", step=3 * w,
            data=rgb.tobytes(),
        )))  # fmt: skip
        items.append((log_d, DEPTH, RawImage(
            timestamp=ts(td), frame_id=FRAME, width=w, height=h, encoding="16UC1", step=2 * w,
            data=mm.astype("<u2").tobytes(),
        )))  # fmt: skip
    for row in _poses(seq_dir):
        pose = Pose(position=Vector3(x=row[1], y=row[2], z=row[3]),
                    orientation=Quaternion(x=row[4], y=row[5], z=row[6], w=row[7]))  # fmt: skip
        items.append((stamp_ns(row[0]), GT, PoseInFrame(timestamp=ts(stamp_ns(row[0])),
                                                        frame_id="world", pose=pose)))  # fmt: skip
    writer = foxglove.open_mcap(out, context=ctx)
    for log, topic, msg in _in_log_order(items):
        chans[topic].log(msg, log_time=log)
    writer.close()


def write_foxglove_protobuf(seq_dir: Path, out: Path) -> None:
    """Protobuf through ``mcap-protobuf-support`` + ``foxglove-schemas-protobuf``: PNG
    CompressedImage colour and 16-bit PNG depth, CameraCalibration, FrameTransform ground
    truth (child ``camera``)."""
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
    from mcap_protobuf.writer import Writer

    def stamped(msg: object, ns: int) -> object:
        msg.timestamp.FromNanoseconds(ns)
        return msg

    items = []
    k = _k(seq_dir)
    for t, td, log_d, rgb, mm, _ in _frames(seq_dir):
        h, w = mm.shape
        cal = CameraCalibration(frame_id=FRAME, width=w, height=h, distortion_model="plumb_bob",
                                D=[0.0] * 5, K=k)  # fmt: skip
        items.append((t + LOG_DELAY_NS, INFO, stamped(cal, t)))
        png = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))[1].tobytes()
        items.append(
            (
                t + LOG_DELAY_NS,
                RGB + "/compressed",
                stamped(CompressedImage(frame_id=FRAME, format="png", data=png), t),
            )
        )
        dpng = cv2.imencode(".png", mm)[1].tobytes()
        items.append(
            (
                log_d,
                DEPTH + "/compressed",
                stamped(CompressedImage(frame_id=FRAME, format="png", data=dpng), td),
            )
        )
    for row in _poses(seq_dir):
        tr = FrameTransform(parent_frame_id="world", child_frame_id="camera")
        tr.translation.x, tr.translation.y, tr.translation.z = row[1:4]
        tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w = row[4:]
        items.append((stamp_ns(row[0]), TF, stamped(tr, stamp_ns(row[0]))))
    with out.open("wb") as f, Writer(f) as writer:
        for log, topic, msg in _in_log_order(items):
            writer.write_message(topic, msg, log_time=log, publish_time=log)


def _schema(title: str, fields: dict[str, str]) -> bytes:
    props = {k: {"type": v} for k, v in fields.items()}
    return json.dumps({"title": title, "type": "object", "properties": props}).encode()


_TIME = "object"
JSON_SCHEMAS = {
    "foxglove.RawImage": _schema(
        "foxglove.RawImage",
        {
            "timestamp": _TIME,
            "frame_id": "string",
            "width": "integer",
            "height": "integer",
            "encoding": "string",
            "step": "integer",
            "data": "string",
        },
    ),
    "foxglove.CameraCalibration": _schema(
        "foxglove.CameraCalibration",
        {
            "timestamp": _TIME,
            "frame_id": "string",
            "width": "integer",
            "height": "integer",
            "distortion_model": "string",
            "D": "array",
            "K": "array",
        },
    ),
    "foxglove.FrameTransforms": _schema("foxglove.FrameTransforms", {"transforms": "array"}),
}


def write_foxglove_json(seq_dir: Path, out: Path) -> None:
    """JSON through the ``mcap`` package's ``Writer``: RawImage bgr8 colour and 32FC1 depth
    (metres, NaN = none; bytes as base64 text), CameraCalibration, FrameTransforms ground
    truth (child ``camera``)."""
    from mcap.writer import Writer

    def ts(ns: int) -> dict:
        return {"sec": ns // 10**9, "nsec": ns % 10**9}

    def raw(ns: int, a: np.ndarray, enc: str) -> dict:
        h, w = a.shape[:2]
        return {"timestamp": ts(ns), "frame_id": FRAME, "width": w, "height": h,
                "encoding": enc, "step": a.nbytes // h,
                "data": base64.b64encode(a.tobytes()).decode()}  # fmt: skip

    items = []
    k = _k(seq_dir)
    for t, td, log_d, rgb, mm, depth_m in _frames(seq_dir):
        h, w = mm.shape
        items.append((t + LOG_DELAY_NS, INFO, {"timestamp": ts(t), "frame_id": FRAME,
                      "width": w, "height": h, "distortion_model": "plumb_bob",
                      "D": [0.0] * 5, "K": k}))  # fmt: skip
        items.append((t + LOG_DELAY_NS, RGB, raw(t, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), "bgr8")))
        metres = np.where(depth_m > 0, depth_m, np.nan).astype("<f4")
        items.append((log_d, DEPTH, raw(td, metres, "32FC1")))
    for row in _poses(seq_dir):
        ns = stamp_ns(row[0])
        tr = {"timestamp": ts(ns), "parent_frame_id": "world", "child_frame_id": "camera",
              "translation": dict(zip("xyz", row[1:4], strict=True)),
              "rotation": dict(zip("xyzw", row[4:], strict=True))}  # fmt: skip
        items.append((ns, TF, {"transforms": [tr]}))
    schema_of = {RGB: "foxglove.RawImage", DEPTH: "foxglove.RawImage",
                 INFO: "foxglove.CameraCalibration", TF: "foxglove.FrameTransforms"}  # fmt: skip
    with out.open("wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="slimseg tests")
        sids = {n: writer.register_schema(n, "jsonschema", d) for n, d in JSON_SCHEMAS.items()}
        cids = {t: writer.register_channel(t, "json", sids[s]) for t, s in schema_of.items()}
        for log, topic, msg in _in_log_order(items):
            data = json.dumps(msg).encode()
            writer.add_message(cids[topic], log_time=log, data=data, publish_time=log)
        writer.finish()


def write_unsupported(out: Path) -> None:
    """An MCAP whose only channel holds a FlatBuffers schema (slimseg decodes none)."""
    from mcap.writer import Writer

    with out.open("wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="slimseg tests")
        sid = writer.register_schema("foxglove.RawImage", "flatbuffer", b"\x00" * 16)
        cid = writer.register_channel(RGB, "flatbuffer", sid)
        for i in range(3):
            writer.add_message(cid, log_time=i, data=b"\x00" * 8, publish_time=i)
        writer.finish()
