"""Foxglove messages (``foxglove.RawImage``, ``CompressedImage``, ``CameraCalibration``,
``PoseInFrame``, ``FrameTransform`` and ``FrameTransforms``), protobuf-decoded or JSON, in the
shape of the ROS 2 message slimseg reads for the same role, so one image decoder and one pose
reader serve both: a raw image has ``height, width, encoding, step, is_bigendian, data``; a
calibration ``k``; a pose ``header.stamp.sec / .nanosec`` and ``pose.position /
.orientation``; transforms ``transforms[i].child_frame_id`` and ``.transform.translation /
.rotation``.

A protobuf message keeps its bytes fields as ``bytes`` and its time as
``google.protobuf.Timestamp`` (``seconds, nanos``); the JSON encoding holds bytes as base64
text and time as ``{"sec", "nsec"}``. Both are read here, nowhere else.
"""

from __future__ import annotations

import base64
from types import SimpleNamespace

import numpy as np

from slimseg.data.bags.reader import CAMERA_INFO, COMPRESSED, IMAGE, POSE, TF, Header

FOXGLOVE_ROLES = {
    "foxglove.RawImage": IMAGE,
    "foxglove.CompressedImage": COMPRESSED,
    "foxglove.CameraCalibration": CAMERA_INFO,
    "foxglove.PoseInFrame": POSE,
    "foxglove.FrameTransform": TF,
    "foxglove.FrameTransforms": TF,
}


def _get(msg: object, name: str, default: object = None) -> object:
    """Field ``name`` of a protobuf message or a JSON object."""
    if isinstance(msg, dict):
        return msg.get(name, default)
    return getattr(msg, name, default)


def _stamp_ns(msg: object) -> int:
    t = _get(msg, "timestamp")
    if t is None:
        raise ValueError("message has no timestamp")
    if isinstance(t, dict):
        sec, nsec = int(t.get("sec", 0)), int(t.get("nsec", 0))
    else:
        sec, nsec = int(t.seconds), int(t.nanos)
    if not 0 <= nsec < 1_000_000_000:
        raise ValueError(f"timestamp nanoseconds {nsec} out of range")
    return sec * 1_000_000_000 + nsec


def foxglove_header(msg: object) -> Header:
    """The stamp and ``frame_id`` of a Foxglove message (``ValueError`` without a stamp)."""
    return Header(_stamp_ns(msg), str(_get(msg, "frame_id", "") or ""))


def _bytes(value: object) -> np.ndarray:
    raw = base64.b64decode(value) if isinstance(value, str) else bytes(value or b"")
    return np.frombuffer(raw, np.uint8)


def _ros_header(ns: int, frame_id: str) -> SimpleNamespace:
    sec, nsec = divmod(ns, 1_000_000_000)
    return SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nsec), frame_id=frame_id)


def _vec(v: object, keys: str) -> SimpleNamespace:
    return SimpleNamespace(**{k: float(_get(v, k, 0.0) or 0.0) for k in keys})


def _transform(msg: object) -> SimpleNamespace:
    return SimpleNamespace(
        header=_ros_header(_stamp_ns(msg), str(_get(msg, "parent_frame_id", ""))),
        child_frame_id=str(_get(msg, "child_frame_id", "")),
        transform=SimpleNamespace(
            translation=_vec(_get(msg, "translation"), "xyz"),
            rotation=_vec(_get(msg, "rotation"), "xyzw"),
        ),
    )


def foxglove_view(schema: str, msg: object) -> object:
    """``msg`` (of Foxglove ``schema``) in the shape of the ROS 2 message of its role (see the
    module docstring); other schemas are returned as they are."""
    if schema == "foxglove.RawImage":
        return SimpleNamespace(
            height=int(_get(msg, "height", 0)), width=int(_get(msg, "width", 0)),
            encoding=str(_get(msg, "encoding", "")), step=int(_get(msg, "step", 0)),
            is_bigendian=0, data=_bytes(_get(msg, "data")),
        )  # fmt: skip
    if schema == "foxglove.CompressedImage":
        return SimpleNamespace(format=str(_get(msg, "format", "")), data=_bytes(_get(msg, "data")))
    if schema == "foxglove.CameraCalibration":
        k = [float(v) for v in _get(msg, "K", None) or [0.0] * 9]
        return SimpleNamespace(
            width=int(_get(msg, "width", 0)), height=int(_get(msg, "height", 0)),
            distortion_model=str(_get(msg, "distortion_model", "")), k=k, K=k,
        )  # fmt: skip
    if schema == "foxglove.PoseInFrame":
        pose = _get(msg, "pose")
        return SimpleNamespace(
            header=_ros_header(_stamp_ns(msg), str(_get(msg, "frame_id", ""))),
            pose=SimpleNamespace(
                position=_vec(_get(pose, "position"), "xyz"),
                orientation=_vec(_get(pose, "orientation"), "xyzw"),
            ),
        )
    if schema == "foxglove.FrameTransform":
        return SimpleNamespace(transforms=[_transform(msg)])
    if schema == "foxglove.FrameTransforms":
        return SimpleNamespace(transforms=[_transform(t) for t in _get(msg, "transforms", [])])
    return msg
