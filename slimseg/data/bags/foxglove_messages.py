"""Foxglove messages (``foxglove.RawImage``, ``CompressedImage``, ``CameraCalibration``,
``PoseInFrame``, ``FrameTransform`` and ``FrameTransforms``), protobuf-decoded or JSON, in the
shape of the ROS 2 message slimseg reads for the same role, so one image decoder and one pose
reader serve both: a raw image has ``height, width, encoding, step, is_bigendian, data``; a
calibration ``k``; a pose ``header.stamp.sec / .nanosec`` and ``pose.position /
.orientation``; transforms ``transforms[i].child_frame_id`` and ``.transform.translation /
.rotation``.

A protobuf message keeps its bytes fields as ``bytes`` and its time as
``google.protobuf.Timestamp`` (``seconds, nanos``); the JSON encoding holds bytes as base64
text and time as ``{"sec", "nsec"}``. Both are checked field by field against the schema
(:mod:`slimseg.data.bags.foxglove_fields`) before a value is used, and shaped here.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from slimseg.data.bags.foxglove_fields import SCHEMAS, read
from slimseg.data.bags.header import CAMERA_INFO, COMPRESSED, IMAGE, NS_PER_S, POSE, TF, Header

FOXGLOVE_ROLES = {
    "foxglove.RawImage": IMAGE,
    "foxglove.CompressedImage": COMPRESSED,
    "foxglove.CameraCalibration": CAMERA_INFO,
    "foxglove.PoseInFrame": POSE,
    "foxglove.FrameTransform": TF,
    "foxglove.FrameTransforms": TF,
}
_STAMPED = {"timestamp": SCHEMAS["foxglove.RawImage"]["timestamp"], "frame_id": "string"}


def foxglove_header(msg: object) -> Header:
    """The stamp and ``frame_id`` of a Foxglove image message, checked (``ValueError``)."""
    v = read(msg, _STAMPED, "message")
    return Header(v["timestamp"], v["frame_id"])


def _ros_header(ns: int, frame_id: str) -> SimpleNamespace:
    sec, nsec = divmod(ns, NS_PER_S)
    return SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nsec), frame_id=frame_id)


def _ns(values: dict) -> SimpleNamespace:
    return SimpleNamespace(**values)


def _transform(t: dict) -> SimpleNamespace:
    return SimpleNamespace(
        header=_ros_header(t["timestamp"], t["parent_frame_id"]),
        child_frame_id=t["child_frame_id"],
        transform=SimpleNamespace(translation=_ns(t["translation"]), rotation=_ns(t["rotation"])),
    )


def foxglove_view(schema: str, msg: object) -> object:
    """``msg`` (of Foxglove ``schema``) checked field by field (:func:`read`) and given the
    shape of the ROS 2 message of its role (see the module docstring); ``ValueError`` naming a
    field that is not what the schema declares."""
    if schema not in SCHEMAS:
        return msg
    v = read(msg, SCHEMAS[schema], schema.removeprefix("foxglove."))
    if schema == "foxglove.RawImage":
        return SimpleNamespace(
            height=v["height"], width=v["width"], encoding=v["encoding"], step=v["step"],
            is_bigendian=0, data=np.frombuffer(v["data"], np.uint8),
        )  # fmt: skip
    if schema == "foxglove.CompressedImage":
        return SimpleNamespace(format=v["format"], data=np.frombuffer(v["data"], np.uint8))
    if schema == "foxglove.CameraCalibration":
        return SimpleNamespace(
            width=v["width"], height=v["height"], distortion_model=v["distortion_model"],
            k=v["K"], K=v["K"],
        )  # fmt: skip
    if schema == "foxglove.PoseInFrame":
        return SimpleNamespace(
            header=_ros_header(v["timestamp"], v["frame_id"]),
            pose=SimpleNamespace(
                position=_ns(v["pose"]["position"]), orientation=_ns(v["pose"]["orientation"])
            ),
        )
    if schema == "foxglove.FrameTransform":
        return SimpleNamespace(transforms=[_transform(v)])
    return SimpleNamespace(transforms=[_transform(t) for t in v["transforms"]])
