"""Hypothesis strategies for every field of every Foxglove message slimseg reads (issue #62): a
JSON message whose fields hold any JSON value, and a protobuf message of any field values,
goes through :meth:`BagFile.decode` / :meth:`BagFile.header` (the reader's boundary) and the
image decoders; either it is refused with one ``SlimsegError`` line naming the message, or
every value that comes out is what the schema declares (whole numbers in range, finite
floats, bytes of the size the image needs). Derandomized: CI sees the same cases every run."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from types import SimpleNamespace

import hostile_recordings as hr
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from slimseg.data.bags.foxglove_fields import SCHEMAS
from slimseg.data.bags.image_messages import colour_from_image, depth_from_image
from slimseg.data.bags.reader import BagFile
from slimseg.errors import SlimsegError

pytest.importorskip("mcap_protobuf")

EXAMPLES = int(os.environ.get("SLIMSEG_PROPERTY_EXAMPLES", "120"))
FAST = settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
                suppress_health_check=list(HealthCheck))  # fmt: skip

JSON_VALUES = st.recursive(
    st.one_of(
        st.none(), st.booleans(), st.integers(-(2**70), 2**70), st.text(max_size=16),
        st.floats(allow_nan=True, allow_infinity=True),
        st.sampled_from(["AAAA", "////", "=", "\x1b[2J", "rgb8", "16UC1", "mono8"]),
    ),
    lambda inner: st.one_of(st.lists(inner, max_size=10),
                            st.dictionaries(st.sampled_from(["sec", "nsec", "x", "y"]), inner)),
    max_leaves=12,
)  # fmt: skip


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("prop")
    return {
        "json": hr.json_recording(root / "j.mcap"),
        "protobuf": hr.protobuf_recording(root / "p.mcap"),
    }


def _check(bag: BagFile, topic: str, raw: bytes, schema: str) -> None:
    """The property for one message on ``topic`` of ``bag``."""
    try:
        bag.header(raw, topic, 0)
        msg = bag.decode(raw, bag.topics[topic], topic, 0)
        if schema == "foxglove.RawImage":
            img = (depth_from_image if msg.encoding in ("16UC1", "32FC1", "mono16")
                   else colour_from_image)(msg)  # fmt: skip
            assert img.shape[:2] == (msg.height, msg.width)
        else:
            assert len(msg.k) == 9 and all(math.isfinite(v) for v in msg.k)
            assert 0 <= msg.width < 2**32 and 0 <= msg.height < 2**32
    except SlimsegError as e:
        assert "\n" not in str(e) and f"message 0 on {topic}" in str(e)
    except ValueError as e:  # the image decoders' refusals (BagSequence names them in one line)
        assert "\n" not in str(e)


@given(field=st.sampled_from(sorted(SCHEMAS["foxglove.RawImage"])), value=JSON_VALUES)
@FAST
def test_any_json_value_in_any_image_field(recordings, field: str, value: object) -> None:
    with BagFile(recordings["json"]) as bag:
        raw = next(r for _, _, r in bag.messages([hr.COLOUR]))
        msg = json.loads(raw)
        msg[field] = value
        _check(bag, hr.COLOUR, json.dumps(msg).encode(), "foxglove.RawImage")


@given(field=st.sampled_from(sorted(SCHEMAS["foxglove.CameraCalibration"])), value=JSON_VALUES)
@FAST
def test_any_json_value_in_any_calibration_field(recordings, field: str, value: object) -> None:
    with BagFile(recordings["json"]) as bag:
        raw = next(r for _, _, r in bag.messages([hr.INFO]))
        msg = json.loads(raw)
        msg[field] = value
        _check(bag, hr.INFO, json.dumps(msg).encode(), "foxglove.CameraCalibration")


@given(
    width=st.integers(0, 2**32 - 1), height=st.integers(0, 2**32 - 1),
    step=st.integers(0, 2**32 - 1), data=st.binary(max_size=700),
    encoding=st.sampled_from(["rgb8", "bgr8", "mono8", "16UC1", "32FC1", "", "yuv422"]),
    sec=st.integers(-(2**63), 2**63 - 1), nanos=st.integers(-(2**31), 2**31 - 1),
)  # fmt: skip
@FAST
def test_any_protobuf_image_values(recordings, width, height, step, data, encoding, sec, nanos):
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    m = RawImage(width=width, height=height, step=step, data=data, encoding=encoding)
    m.timestamp.seconds, m.timestamp.nanos = sec, nanos
    with BagFile(recordings["protobuf"]) as bag:
        _check(bag, hr.COLOUR, m.SerializeToString(), "foxglove.RawImage")


@given(k=st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=12))
@FAST
def test_any_protobuf_calibration_k(recordings, k: list[float]) -> None:
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration

    with BagFile(recordings["protobuf"]) as bag:
        _check(bag, hr.INFO, CameraCalibration(K=k, width=16, height=12).SerializeToString(),
               "foxglove.CameraCalibration")  # fmt: skip


def test_the_views_bytes_are_the_messages(recordings) -> None:
    with BagFile(recordings["protobuf"]) as bag:
        raw = next(r for _, _, r in bag.messages([hr.COLOUR]))
        img = colour_from_image(bag.decode(raw, bag.topics[hr.COLOUR], hr.COLOUR))
    assert np.array_equal(img, hr.colour(0))


def _base(schema: str) -> dict:
    """A well-formed JSON message of ``schema`` (every field of :data:`SCHEMAS` set)."""
    t = {"sec": 1, "nsec": 2}
    vec, quat = {"x": 0.0, "y": 1.0, "z": 2.0}, {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
    tr = {"timestamp": t, "parent_frame_id": "w", "child_frame_id": "c", "translation": vec,
          "rotation": quat}  # fmt: skip
    return {
        "foxglove.RawImage": {"timestamp": t, "frame_id": "f", "width": 2, "height": 1,
                              "encoding": "mono8", "step": 2, "data": "AAA="},
        "foxglove.CompressedImage": {"timestamp": t, "frame_id": "f", "format": "png",
                                     "data": "AAA="},
        "foxglove.CameraCalibration": {"timestamp": t, "frame_id": "f", "width": 2, "height": 1,
                                       "distortion_model": "", "K": hr.K},
        "foxglove.PoseInFrame": {"timestamp": t, "frame_id": "f",
                                 "pose": {"position": vec, "orientation": quat}},
        "foxglove.FrameTransform": tr,
        "foxglove.FrameTransforms": {"transforms": [tr, tr]},
    }[schema]  # fmt: skip


def _paths(fields: dict, prefix: tuple = ()) -> list[tuple]:
    """Every field of a :data:`SCHEMAS` row as a key path (nested messages and lists too)."""
    out = []
    for name, kind in fields.items():
        out.append((*prefix, name))
        if isinstance(kind, dict):
            out += _paths(kind, (*prefix, name))
        elif isinstance(kind, list):
            out += _paths(kind[0], (*prefix, name, 0))
    return out


FIELD_PATHS = [(s, p) for s in sorted(SCHEMAS) for p in _paths(SCHEMAS[s])]


@given(where=st.sampled_from(FIELD_PATHS), value=JSON_VALUES)
@FAST
def test_any_json_value_in_any_field_of_every_schema(where: tuple, value: object) -> None:
    """Every field of every Foxglove schema read (nested ones included): the view is refused
    with a ValueError naming a field, or every number in it is finite."""
    from slimseg.data.bags.foxglove_messages import foxglove_header, foxglove_view

    schema, path = where
    msg = _base(schema)
    parent = msg
    for key in path[:-1]:
        parent = parent[key]
    parent[path[-1]] = value
    try:
        view = foxglove_view(schema, msg)
        if "timestamp" in msg:
            foxglove_header(msg)
    except ValueError as e:
        assert "\n" not in str(e) and str(e)
        return
    for number in _numbers(view):
        assert math.isfinite(number)


def _numbers(v: object) -> list[float]:
    if isinstance(v, bool):
        return []
    if isinstance(v, (int, float)):
        return [float(v)]
    if isinstance(v, (list, tuple)):
        return [x for item in v for x in _numbers(item)]
    if isinstance(v, np.ndarray):
        return []
    if isinstance(v, SimpleNamespace):
        return [x for item in vars(v).values() for x in _numbers(item)]
    return []
