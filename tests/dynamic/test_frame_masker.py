"""The per-frame chain every command runs (``FrameMasker``): the caller's keypoints, bad
frames, and late model results moved by each object's own motion."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from slimseg.data.synth.sequence import write_sequence
from slimseg.data.tum import TumSequence, mask_name
from slimseg.dynamic.annotations import AnnotationInstances
from slimseg.dynamic.chain_config import ChainConfig, TrackPlan
from slimseg.dynamic.epipolar import PreviousFrame, orb_features
from slimseg.dynamic.frame_masker import FrameError, FrameMasker, segmenter_for
from slimseg.dynamic.masking_settings import PAPERS
from slimseg.dynamic.model_rate import EVERY_FRAME, ModelRate
from slimseg.dynamic.object_motion import (
    _subset_medians,
    inside_boxes,
    object_shifts,
)
from slimseg.dynamic.threshold import inside
from slimseg.dynamic.track_run import TrackedSequence
from slimseg.dynamic.track_settings import COAST
from slimseg.errors import SlimsegError
from slimseg.objects import Objects
from slimseg.sequence.sequence_run import run_sequence


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("chain") / "seq"
    write_sequence(root, seed=3, index=0, frames=12, size=(320, 240), preset="walking_xyz")
    return root


def _masker(seq: Path, track=None, rate: ModelRate = EVERY_FRAME, **kw) -> FrameMasker:
    """The chain on ``seq``'s ground-truth instances; ``kw``: :class:`ChainConfig` fields."""
    inst = AnnotationInstances(seq)
    config = ChainConfig(track=TrackPlan(track, rate), **kw)
    return FrameMasker(segmenter_for(inst), inst.mobility, config)


@pytest.mark.parametrize(
    ("mode", "track"), [("fusion", None), ("fusion+epipolar", None), ("fusion+epipolar", COAST)]
)
def test_the_callers_keypoints_are_classified_as_the_chains_own(
    sequence: Path, mode: str, track
) -> None:
    """Given the chain's own ORB keypoints back, every decision and mask is the same: the
    caller's keypoints replace only what is classified (the epipolar check keeps its own)."""
    seq = TumSequence(sequence)
    with _masker(sequence, mode=mode, track=track) as a, _masker(sequence, mode=mode,
                                                                 track=track) as b:  # fmt: skip
        shares = []
        for i in range(len(seq)):
            rgb, depth, stamp = seq.load(i)
            own = a.step(rgb, depth, stamp)
            given = b.step(rgb, depth, stamp, keypoints=own.keypoints.copy())
            assert np.array_equal(own.mask, given.mask)
            assert np.array_equal(own.dynamic, given.dynamic)
            shares.append(own.dynamic.mean())
    assert 0 < max(shares) < 1


def test_a_loop_over_the_chain_writes_what_slimseg_dynamic_writes(
    sequence: Path, tmp_path: Path
) -> None:
    run_sequence(
        AnnotationInstances(sequence),
        sequence,
        tmp_path,
        ChainConfig(mode="fusion"),
        progress=False,
    )
    seq = TumSequence(sequence)
    with _masker(sequence, fps=seq.fps, camera=seq.camera.pinhole) as m:
        for i in range(len(seq)):
            out = m.step(*seq.load(i))
            written = cv2.imread(str(tmp_path / "masks" / mask_name(out.stamp)), 0)
            assert np.array_equal(out.mask, written)
            assert out.objects.track_ids.tolist() == [-1] * len(out.objects)
            assert out.timing.latency >= out.timing.logic > 0


def test_bad_frames_are_refused_in_one_line(sequence: Path) -> None:
    seq = TumSequence(sequence)
    rgb, depth, stamp = seq.load(0)
    m = _masker(sequence)
    for bad, msg in (
        ((rgb.astype(np.float32),), "expected uint8 [H, W, 3]"),
        ((rgb[..., 0],), "expected uint8 [H, W, 3]"),
        ((rgb, depth[:-1]), "expected [H, W] = [240, 320]"),
        ((rgb, (depth * 5000).astype(np.uint16)), "give depth_scale"),
        ((rgb, depth, stamp, np.zeros((4, 3))), "expected finite [N, 2]"),
    ):
        with pytest.raises(FrameError, match=re.escape(msg)) as e:
            m.step(*bad)
        assert "\n" not in str(e.value) and str(e.value).startswith("frame 0:")
    m.step(rgb, depth, stamp)
    with pytest.raises(FrameError, match="the first frame was 320x240"):
        m.step(rgb[:200], None, stamp)
    with pytest.raises(SlimsegError, match="depth_scale nan"):
        _masker(sequence, depth_scale=float("nan"))
    scaled = _masker(sequence, depth_scale=5000.0)
    raw = np.round(depth * 5000).astype(np.uint16)
    metres = _masker(sequence).step(rgb, raw / 5000.0, stamp)
    assert np.array_equal(scaled.step(rgb, raw, stamp).mask, metres.mask)
    with pytest.raises(SlimsegError, match="mode 'boxes'"):
        _masker(sequence, mode="boxes")


def _scene(background: np.ndarray, patch: np.ndarray, x: int, y: int) -> np.ndarray:
    img = background.copy()
    img[y : y + patch.shape[0], x : x + patch.shape[1]] = patch
    return img


def test_object_shifts_follow_the_objects_own_matches() -> None:
    """A textured block moves (+9, -4) px over a still textured background: the matches
    inside its mask say so; inside a textureless region there is nothing to say (NaN)."""
    rng = np.random.default_rng(0)
    bg = np.kron(rng.integers(0, 256, (30, 40, 3), dtype=np.uint8), np.ones((8, 8, 1), np.uint8))
    block = np.kron(rng.integers(0, 256, (8, 8, 3), dtype=np.uint8), np.ones((8, 8, 1), np.uint8))
    old, new = _scene(bg, block, 100, 80), _scene(bg, block, 109, 76)
    fo, fn = orb_features(old, 1000), orb_features(new, 1000)
    masks = np.zeros((2, 240, 320), bool)
    masks[0, 80:144, 100:164] = True
    flat = np.zeros((2, 4), np.float32)
    flat[0], flat[1] = [100, 80, 164, 144], [0, 0, 2, 2]
    on = inside(fo.keypoints, masks)
    shifts = object_shifts(fo, fn, on, min_matches=6)
    assert shifts[0] == pytest.approx([9, -4], abs=1.0) and np.isnan(shifts[1]).all()
    boxes = object_shifts(fo, fn, inside_boxes(flat, fo.keypoints), 6)  # box-only: the box
    assert boxes[0] == pytest.approx([9, -4], abs=1.0)
    assert np.isnan(object_shifts(fo, fn, on, min_matches=10_000)).all()


def test_a_late_result_lands_where_the_object_is_now() -> None:
    """Frame 0's detection delivered on frame 3 (lag 3) of a block moving (+6, 0) px per frame
    with a still camera: moved by its own matches it lands on the block; with ``own_matches``
    0 (camera motion and a track velocity it does not have yet) it stays 18 px behind."""
    rng = np.random.default_rng(1)
    bg = np.kron(rng.integers(0, 256, (30, 40, 3), dtype=np.uint8), np.ones((8, 8, 1), np.uint8))
    block = np.kron(rng.integers(0, 256, (8, 8, 3), dtype=np.uint8), np.ones((8, 8, 1), np.uint8))
    frames = [_scene(bg, block, 60 + 6 * k, 90) for k in range(4)]
    mask = np.zeros((1, 240, 320), bool)
    mask[0, 90:154, 60:124] = True
    det = Objects(np.array([[60, 90, 124, 154]], np.float32), np.array([0.9], np.float32),
                  np.zeros(1, np.int64), mask, (240, 320))  # fmt: skip
    centres = {}
    for late in (6, 0):
        settings = COAST.with_values(own_matches=late)
        stage = TrackedSequence(settings, np.array([1.0]), mover_prior=0.5)
        previous = None
        for k, img in enumerate(frames):
            feats = orb_features(img, 1000)
            dets, lag = (det, 0) if k == 0 else ((det, 3) if k == 3 else (None, 0))
            frame = stage.inputs(feats, dets, 0.1, None, previous, lag).objects
            previous = PreviousFrame(feats)
        centres[late] = np.nonzero(frame.masks[frame.det_index >= 0][0])[1].mean()
    assert centres[6] == pytest.approx(92 + 18, abs=1.5)
    assert centres[0] == pytest.approx(92, abs=1.5)


def test_the_objects_are_what_the_segmenter_returns(sequence: Path) -> None:
    """A custom segmenter (any callable) feeds the chain; its threshold is the chain's."""
    seen = []

    def segment(rgb: np.ndarray, stamp: float, conf: float) -> Objects:
        seen.append(conf)
        return Objects.empty(rgb.shape[:2])

    rgb = TumSequence(sequence).load(0)[0]
    with FrameMasker(segment, [1.0], ChainConfig(track=TrackPlan(COAST))) as m:
        out = m.step(rgb)
    assert seen == [min(m.config.masking.conf, COAST.low)] and not out.mask.any()
    assert len(out.objects) == 0 and out.model_ran and out.stamp == 0.0


def test_subset_medians_are_numpys_medians() -> None:
    """All objects' medians at once (ties and even counts included) equal ``np.median``."""
    rng = np.random.default_rng(0)
    for _ in range(200):
        p, m = int(rng.integers(1, 60)), int(rng.integers(1, 8))
        values = rng.normal(size=p).round(1)
        members = rng.random((m, p)) < 0.5
        members[:, rng.integers(0, p)] = True
        expected = [np.median(values[row]) for row in members]
        assert np.allclose(_subset_medians(values, members), expected)


def test_settings_that_cannot_act_are_said_once_or_refused(caplog) -> None:
    """The shipped preset's motion layers and stillness need the camera, the depth cut depth:
    without them the chain says so once (the settings by name), or refuses when strict."""
    hw = (48, 64)
    rgb = np.zeros((*hw, 3), np.uint8)

    def nothing(img: np.ndarray, stamp: float, conf: float) -> Objects:
        return Objects.empty(hw)

    with caplog.at_level("WARNING", logger="slimseg"), FrameMasker(nothing, [1.0]) as m:
        for _ in range(3):  # no camera
            m.step(rgb, np.ones(hw, np.float32))
    said = [r.getMessage() for r in caplog.records if "cannot act" in r.getMessage()]
    assert len(said) == 1 and "no camera intrinsics" in said[0], said
    assert "motion_layer_px 100" in said[0] and "still_frames 20" in said[0]
    assert "cut_behind_m" not in said[0]  # the depth cut needs depth only
    caplog.clear()
    camera = ChainConfig(camera=(50.0, 50.0, 32.0, 24.0))
    with caplog.at_level("WARNING", logger="slimseg"), FrameMasker(nothing, [1.0], camera) as m:
        m.step(rgb, np.ones(hw, np.float32))  # all it needs: nothing said
        m.step(rgb)  # a frame without depth: said once, the depth levers by name
        m.step(rgb)
    said = [r.getMessage() for r in caplog.records if "cannot act" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith("frame 1: no depth image"), said
    assert "cut_behind_m 0.5" in said[0] and "at most 0.25" in said[0]
    with pytest.raises(FrameError, match="motion_layer_px 100, still_frames 20 cannot act"):
        FrameMasker(nothing, [1.0], ChainConfig(strict=True))
    papers = ChainConfig(masking=PAPERS, strict=True)  # no lever needs the camera: fine
    with FrameMasker(nothing, [1.0], papers) as m:
        m.step(rgb)
