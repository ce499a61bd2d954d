"""Model metadata read as one schema (issue #62, finding 6): a tampered ``end2end`` entry, a
deeply nested value or an ``int8.target`` holding escape codes ends in one ``SlimsegError``
line naming the file and the field, never a traceback, and nothing of it reaches the terminal
raw."""

from __future__ import annotations

import json

import pytest

from slimseg.deploy.metadata import precision_label, read_onnx_metadata, to_metadata_props
from slimseg.errors import SlimsegError

BASE = {"names": ["person", "car"], "imgsz": [160, 160], "family": "yolov8", "task": "segment",
        "end2end": {"conf": 0.1, "iou": 0.7, "max_det": 300, "class_aware": True,
                    "mask_margin_px": 4}}  # fmt: skip


def _props(**change: object) -> dict[str, str]:
    meta = {**BASE, **change}
    return to_metadata_props({k: v for k, v in meta.items() if v is not None})


def test_a_valid_end2end_entry_reads() -> None:
    meta = read_onnx_metadata("m.onnx", _props())
    assert meta["end2end"]["max_det"] == 300


@pytest.mark.parametrize(
    ("end2end", "field"),
    [
        ({}, "'end2end' must be an object holding conf, iou, max_det"),
        ([1, 2], "'end2end' must be an object"),
        ({**BASE["end2end"], "max_det": "abc"}, "end2end.max_det is 'abc'"),
        ({**BASE["end2end"], "max_det": 2.5}, "end2end.max_det is 2.5"),
        ({**BASE["end2end"], "max_det": 0}, "end2end.max_det is 0"),
        ({**BASE["end2end"], "conf": "high"}, "end2end.conf is 'high'"),
        ({**BASE["end2end"], "conf": float("nan")}, "end2end.conf is nan"),
        ({**BASE["end2end"], "iou": 0}, "end2end.iou is 0"),
        ({**BASE["end2end"], "conf": True}, "end2end.conf is True"),
    ],
)
def test_a_tampered_end2end_entry_is_one_line(end2end: object, field: str) -> None:
    with pytest.raises(SlimsegError) as e:
        read_onnx_metadata("m.onnx", _props(end2end=end2end))
    assert str(e.value).startswith("m.onnx: metadata") and field in str(e.value)
    assert "\n" not in str(e.value)


def test_deeply_nested_names_are_refused_not_recursed() -> None:
    props = _props()
    props["names"] = "[" * 100_000 + "]" * 100_000
    with pytest.raises(SlimsegError, match="malformed names"):
        read_onnx_metadata("m.onnx", props)


def test_an_int8_target_with_escape_codes_is_refused_and_never_printed_raw() -> None:
    props = _props(precision="int8", int8={"target": "\x1b[2Jtrt"})
    with pytest.raises(SlimsegError) as e:
        read_onnx_metadata("m.onnx", props)
    assert "\x1b" not in str(e.value) and "\\x1b[2Jtrt" in str(e.value)
    label = precision_label({"precision": "int8\x1b[31m", "int8": {"target": "\x1b[2J"}})
    assert "\x1b" not in label and json.dumps(label)
