"""Specs as data: registry contents, strict loading and clear errors."""

from __future__ import annotations

from pathlib import Path

import pytest

import slimseg
from slimseg.models.registry import get_spec
from slimseg.models.specs import SpecError, load_spec

EXPECTED = (
    {f"yolov8{s}-seg{v}" for s in "ns" for v in ("", "-gs", "-rep", "-gs-rep")}
    | {f"yolov8{s}-seg{v}-hr" for s in "ns" for v in ("", "-gs-rep")}
    | {
        "yolov8n",
        "yolov8s",
        "darknet19-yolov3",
        "msnet-t",
        "msnet-s",
    }
)


def test_list_models_is_the_zoo() -> None:
    assert set(slimseg.list_models()) == EXPECTED


def test_unknown_model_lists_the_valid_names() -> None:
    with pytest.raises(SpecError) as err:
        slimseg.build_model("yolov8x-seg")
    msg = str(err.value)
    assert "yolov8x-seg" in msg and "yolov8s-seg-gs-rep" in msg and "darknet19-yolov3" in msg


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    return path


def test_unknown_field_names_file_field_and_valid_fields(tmp_path: Path) -> None:
    path = _write(
        tmp_path,
        "name: bad\nfamily: yolov8\ntask: segment\nscale: {depth: 0.33, width: 0.25}\n"
        "head: {kind: decoupled, regmax: 16}\n",
    )
    with pytest.raises(SpecError) as err:
        load_spec(path)
    msg = str(err.value)
    assert str(path) in msg and "regmax" in msg and "reg_max" in msg and "head" in msg


@pytest.mark.parametrize(
    ("body", "needle"),
    [
        ("family: yolov9\ntask: segment\n", "family='yolov9' is not one of"),
        ("family: yolov8\ntask: segment\nscale: {depth: 0.33, width: 0.25}\nneck: fpn\n", "fpn"),
        ("family: yolov8\ntask: segment\nscale: {depth: x, width: 0.25}\n", "depth"),
        ("family: yolov8\ntask: segment\n", "scale"),
        ("family: yolov8\ntask: segment\nnum_classes: 0\nscale: {depth: 1, width: 1}\n", ">= 1"),
    ],
)
def test_bad_values_fail_clearly(tmp_path: Path, body: str, needle: str) -> None:
    path = _write(tmp_path, "name: bad\n" + body)
    with pytest.raises(SpecError, match=None) as err:
        slimseg.build_model(path)
    assert needle in str(err.value)
    assert str(path) in str(err.value)


def test_spec_hash_is_stable_and_tracks_changes() -> None:
    a, b = get_spec("yolov8s-seg-gs-rep"), get_spec("yolov8s-seg-gs-rep")
    assert a.hash == b.hash and len(a.hash) == 12
    assert get_spec("yolov8s-seg-gs-rep", 20).hash != a.hash
    assert get_spec("yolov8s-seg-gs").hash != a.hash


def test_build_model_records_spec_and_classes() -> None:
    model = slimseg.build_model("yolov8n-seg-gs", num_classes=7)
    assert model.spec.name == "yolov8n-seg-gs" and model.spec.num_classes == 7
    assert model.num_classes == 7
