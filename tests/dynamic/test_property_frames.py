"""Hostile inputs, generated (issue 47, class 7), for what arrives frame by frame: bag messages
(raw bytes on a topic, decoded image messages with arbitrary fields) and the per-frame object
(``FrameMasker.step`` with arbitrary arrays). Either a result or the project's one-line error,
never another exception; a fixed seed (``derandomize``) keeps CI's cases the same."""

from __future__ import annotations

import contextlib
import os
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from slimseg.data.bags.image_messages import (
    colour_from_compressed,
    colour_from_image,
    depth_from_compressed,
    depth_from_image,
)
from slimseg.data.problems import ImageProblem
from slimseg.data.synth.sequence import write_sequence
from slimseg.data.tum import TUM_DEPTH_SCALE, TumSequence
from slimseg.dynamic.annotations import AnnotationInstances
from slimseg.dynamic.chain_config import ChainConfig
from slimseg.dynamic.frame_masker import FrameMasker, segmenter_for
from slimseg.errors import SlimsegError
from slimseg.objects import Objects

EXAMPLES = int(os.environ.get("SLIMSEG_PROPERTY_EXAMPLES", "120"))  # per property
FAST = settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
ENCODINGS = ["rgb8", "bgr8", "rgba8", "bgra8", "mono8", "16UC1", "mono16", "32FC1", "8UC3", ""]
FORMATS = ["jpeg", "png", "16UC1; compressedDepth png", "32FC1; compressedDepth", "rvl", ""]


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("prop") / "seq"
    write_sequence(folder, 0, 0, 2, (64, 48))
    return folder


@pytest.fixture(scope="module")
def bag(seq: Path):
    pytest.importorskip("rosbags")
    from slimseg.data.bags.from_tum import tum_to_bag
    from slimseg.data.bags.reader import BagFile

    path = seq.parent / "s.mcap"
    tum_to_bag(seq, path)
    with BagFile(path) as f:
        yield f


@FAST
@given(
    raw=st.binary(max_size=200),
    msgtype=st.sampled_from(["sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo",
                             "sensor_msgs/msg/CompressedImage", "geometry_msgs/msg/PoseStamped"]),
)  # fmt: skip
def test_raw_bag_messages(bag, raw: bytes, msgtype: str) -> None:
    with contextlib.suppress(SlimsegError):
        bag.header(raw, "/t")
    with contextlib.suppress(SlimsegError):
        bag.decode(raw, msgtype, "/t")


def _image_messages() -> st.SearchStrategy[SimpleNamespace]:
    return st.builds(
        SimpleNamespace,
        height=st.integers(0, 70000),
        width=st.one_of(st.integers(0, 64), st.integers(0, 70000)),
        step=st.integers(0, 300),
        encoding=st.sampled_from(ENCODINGS),
        is_bigendian=st.booleans(),
        data=st.binary(max_size=600),
    )


@FAST
@given(msg=_image_messages())
def test_image_messages(msg: SimpleNamespace) -> None:
    """What ``BagSequence`` catches (``ValueError``, ``ImageProblem``) and names with the
    topic and stamp; nothing else may escape."""
    for convert in (colour_from_image, depth_from_image):
        with contextlib.suppress(ValueError, ImageProblem):
            out = convert(msg)
            assert out.shape[:2] == (msg.height, msg.width)


@FAST
@given(
    fmt=st.sampled_from(FORMATS),
    head=st.binary(max_size=16),
    body=st.sampled_from([b"", b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff\xe0"]),
    tail=st.binary(max_size=200),
)
def test_compressed_messages(fmt: str, head: bytes, body: bytes, tail: bytes) -> None:
    msg = SimpleNamespace(format=fmt, data=head + body + tail)
    for convert in (colour_from_compressed, depth_from_compressed):
        with contextlib.suppress(ValueError, ImageProblem):
            convert(msg)


_DTYPES = st.sampled_from([np.uint8, np.uint16, np.float32, np.float64, np.int64, np.bool_])


def _arrays(max_dims: int = 4) -> st.SearchStrategy[np.ndarray]:
    return hnp.arrays(
        _DTYPES, hnp.array_shapes(min_dims=0, max_dims=max_dims, min_side=0, max_side=6)
    )


@pytest.fixture(scope="module")
def masker(seq: Path):
    inst = AnnotationInstances(seq)
    with FrameMasker(segmenter_for(inst), inst.mobility) as m:
        yield m


@FAST
@given(
    rgb=st.one_of(_arrays(), st.just("frame"), st.none()),
    depth=st.one_of(st.none(), _arrays(3)),
    stamp=st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True)),
    keypoints=st.one_of(st.none(), _arrays(3)),
)
def test_the_per_frame_object(masker: FrameMasker, rgb, depth, stamp, keypoints) -> None:
    with contextlib.suppress(SlimsegError):
        masker.step(rgb, depth, stamp, keypoints=keypoints)


DEPTH_KINDS = ("none", "nan", "zeros", "negative", "inf", "uint16")


def test_valid_frames_with_odd_depth_and_keypoints(seq: Path) -> None:
    """Well-formed frames whose depth has nothing usable, at any stamp, with keypoints in and
    out of the frame, still mask. Each example gets a masker of its own (the first frame of a
    camera stream: a shared one is fixed to whatever size another test fed it first) whose
    model is the frame's ground truth whatever the stamp (the stamp is the chain's clock here,
    not the key of the lookup); every example must reach the assertion, and does (counted)."""
    rgb, depth, t0 = TumSequence(seq).load(0)
    inst = AnnotationInstances(seq)
    truth = segmenter_for(inst)

    def model(frame: np.ndarray, stamp: float, conf: float) -> Objects:
        return truth(frame, t0, conf)

    config = ChainConfig(depth_scale=TUM_DEPTH_SCALE)  # only the uint16 depth uses it
    fill = {"nan": np.nan, "zeros": 0.0, "negative": -1.0, "inf": np.inf}
    examples, reached = [0], Counter()

    @FAST
    @given(
        depth_kind=st.sampled_from(DEPTH_KINDS),
        stamp=st.one_of(st.none(), st.floats(-1e9, 1e9)),
        n_kp=st.integers(0, 40),
    )
    def frame_masks(depth_kind: str, stamp: float | None, n_kp: int) -> None:
        examples[0] += 1
        d = None if depth_kind == "none" else depth.copy()
        if depth_kind in fill:
            d[:] = fill[depth_kind]
        if depth_kind == "uint16":
            d = np.round(depth * TUM_DEPTH_SCALE).astype(np.uint16)
        kps = np.random.default_rng(n_kp).uniform(-10, 80, (n_kp, 2)).astype(np.float32)
        with FrameMasker(model, inst.mobility, config) as masker:
            out = masker.step(rgb, d, stamp, keypoints=kps)
        assert out.mask.shape == rgb.shape[:2] and out.mask.dtype == np.uint8
        assert out.stamp == (0.0 if stamp is None else stamp)
        reached[depth_kind] += 1

    frame_masks()
    # the property is not vacuous: every example Hypothesis ran got to the assertions, every
    # depth kind among them
    assert examples[0] >= EXAMPLES
    assert sum(reached.values()) == examples[0], (reached, examples[0])
    if 10 * len(DEPTH_KINDS) <= EXAMPLES:  # SLIMSEG_PROPERTY_EXAMPLES may ask for fewer
        assert set(reached) == set(DEPTH_KINDS), reached
