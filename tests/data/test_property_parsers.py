"""Hostile inputs, generated (issue 47, class 7): every parser of a user's file, fed arbitrary
bytes or mutated near-valid content, either parses or raises the project's one-line error
(``SlimsegError``), never another exception. Hypothesis runs each property on a fixed seed
(``derandomize``), so CI sees the same cases every time; the counts are in ``EXAMPLES``."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from slimseg.data.coco_index import build_index, load_coco_json
from slimseg.data.config import load_data_config
from slimseg.data.problems import LoadReport
from slimseg.data.tum import read_camera, read_list, read_trajectory
from slimseg.errors import SlimsegError
from slimseg.utils.manifest import MANIFEST, read_entries
from slimseg.utils.outputs import claim_folder

EXAMPLES = int(os.environ.get("SLIMSEG_PROPERTY_EXAMPLES", "120"))  # per property
FAST = settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

_SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**12), 10**12), st.text(max_size=12),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(["nan", "inf", "-1", "0", "1e-300", "1e400", "../x", "/etc", "\x1b[2J"]),
)  # fmt: skip
JSONISH = st.recursive(
    _SCALARS,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=16,
)


def _mutated(base: bytes) -> st.SearchStrategy[bytes]:
    """``base`` with a slice replaced by arbitrary bytes (near-valid input reaches deeper)."""
    return st.tuples(st.integers(0, len(base)), st.integers(0, 16), st.binary(max_size=24)).map(
        lambda t: base[: t[0]] + t[2] + base[t[0] + t[1] :]
    )


def _bytes_like(*bases: bytes) -> st.SearchStrategy[bytes]:
    return st.one_of(st.binary(max_size=300), *(_mutated(b) for b in bases))


@pytest.fixture(scope="module")
def scratch() -> Path:
    folder = Path(tempfile.mkdtemp(prefix="slimseg-prop-"))
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


def _only_slimseg_errors(parse: Callable[[], object]) -> None:
    with contextlib.suppress(SlimsegError):  # the CLI's one line; anything else: a failure
        parse()


CAMERA = b"%YAML:1.0\nfx: 525.0\nfy: 525.0\ncx: 319.5\ncy: 239.5\ndepth_scale: 5000\nwidth: 640\n"
LIST = b"# rgb\n1305031102.175304 rgb/1305031102.175304.png\n1305031102.211214 rgb/b.png\n"
TRAJ = (
    b"# gt\n1305031102.1753 1.3 0.6 1.6 0.65 0.61 -0.29 -0.33\n1305031102.18 1.3 0.6 1.6 0 0 0 1\n"
)


@FAST
@given(data=_bytes_like(CAMERA))
def test_camera_yaml(scratch: Path, data: bytes) -> None:
    path = scratch / "camera.yaml"
    path.write_bytes(data)
    _only_slimseg_errors(lambda: read_camera(path))


@FAST
@given(value=JSONISH)
def test_camera_yaml_values(scratch: Path, value: object) -> None:
    path = scratch / "camera.yaml"
    path.write_text(json.dumps({"fx": value, "fy": 500, "cx": 1, "cy": 1}, default=str))
    _only_slimseg_errors(lambda: read_camera(path))


@FAST
@given(data=_bytes_like(LIST, TRAJ))
def test_tum_lists_and_trajectories(scratch: Path, data: bytes) -> None:
    path = scratch / "list.txt"
    path.write_bytes(data)
    _only_slimseg_errors(lambda: read_list(path))
    _only_slimseg_errors(lambda: read_trajectory(path))


COCO = {
    "images": [{"id": 1, "file_name": "a.png", "width": 64, "height": 48}],
    "annotations": [{"id": 1, "image_id": 1, "category_id": 1, "bbox": [1, 2, 10, 12],
                     "area": 120, "iscrowd": 0, "segmentation": [[1, 2, 11, 2, 11, 14]]}],
    "categories": [{"id": 1, "name": "person"}],
}  # fmt: skip


@FAST
@given(data=_bytes_like(json.dumps(COCO).encode()))
def test_annotations_json_bytes(scratch: Path, data: bytes) -> None:
    path = scratch / "annotations.json"
    path.write_bytes(data)
    _only_slimseg_errors(lambda: build_index(load_coco_json(path), None, LoadReport(), path))


@FAST
@given(
    section=st.sampled_from(["images", "annotations", "categories"]),
    key=st.sampled_from(["id", "file_name", "width", "height", "image_id", "category_id",
                         "bbox", "area", "iscrowd", "segmentation", "name", "mobility"]),
    value=JSONISH,
)  # fmt: skip
def test_annotations_json_fields(scratch: Path, section: str, key: str, value: object) -> None:
    data = json.loads(json.dumps(COCO))
    data[section][0][key] = value
    path = scratch / "annotations.json"
    path.write_text(json.dumps(data, default=str))
    _only_slimseg_errors(lambda: build_index(load_coco_json(path), None, LoadReport(), path))


@FAST
@given(data=_bytes_like(b'{"written_by": "slimseg t", "format": 2, "entries": {"a": null}}'))
def test_manifests(scratch: Path, data: bytes) -> None:
    folder = scratch / "out"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    (folder / "a").write_text("x")
    (folder / MANIFEST).write_bytes(data)
    read_entries(folder)  # never raises: an unreadable manifest lists nothing
    _only_slimseg_errors(lambda: claim_folder(folder))
    assert (folder / "a").read_text() == "x"


@pytest.fixture(scope="module")
def dataset(scratch: Path) -> Path:
    root = scratch / "ds"
    for split in ("train", "val"):
        (root / split / "images").mkdir(parents=True)
        (root / split / "annotations.json").write_text(json.dumps(COCO))
    return root


DATA_YAML = (
    b"path: .\nnames: [person]\ntrain: {images: train/images, annotations: train/annotations.json}"
    b"\nval: {images: val/images, annotations: val/annotations.json}\n"
)


@FAST
@given(data=_bytes_like(DATA_YAML))
def test_data_yaml(dataset: Path, data: bytes) -> None:
    path = dataset / "data.yaml"
    path.write_bytes(data)
    _only_slimseg_errors(lambda: load_data_config(path))


@FAST
@given(key=st.sampled_from(["path", "names", "train", "val", "mobility", "nc"]), value=JSONISH)
@example(key="path", value="\U00010000")  # found at 2000 cases: JSON's "\ud800\udc00" is
# two lone surrogates to YAML, and a path holding one ended in UnicodeEncodeError
def test_data_yaml_fields(dataset: Path, key: str, value: object) -> None:
    import yaml

    cfg = yaml.safe_load(DATA_YAML)
    cfg[key] = value
    path = dataset / "data.yaml"
    path.write_text(json.dumps(cfg, default=str))  # JSON is YAML
    _only_slimseg_errors(lambda: load_data_config(path))
