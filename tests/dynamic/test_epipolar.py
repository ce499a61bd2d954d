"""Epipolar motion check on hand-built frame pairs: a sideways camera over a layered scene.

The camera translates along x, so a static point at depth Z shifts by f·b/Z px along x
(epipolar lines are horizontal). Layers: a far wall (shift 3 px, Z 4 m), a near floor strip
(8 px, 1.5 m), a standing "person" (6 px, 2 m) and a second "person" that also moves by itself.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import frame_objects

from slimseg.dynamic.epipolar import (
    OrbFeatures,
    PreviousFrame,
    adaptive_epipolar_threshold,
    check_motion,
    epipolar_distance,
    orb_features,
)
from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.masking_settings import PAPERS
from slimseg.dynamic.pipeline import FrameRules, process_frame

H, W = 240, 320
FB = 12.0  # focal length (px) × baseline (m) of the camera step
CAMERA = (300.0, 300.0, 160.0, 120.0)


def _texture(seed: int, h: int, w: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    blocks = rng.integers(0, 256, (h // 4 + 1, w // 4 + 1), dtype=np.uint8)
    return np.kron(blocks, np.ones((4, 4), np.uint8))[:h, :w]


def _render(t: int, mover_step: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, dict]:
    """Gray frame ``t`` (0 or 1), its depth (m) and the frame's object masks."""
    img = np.zeros((H, W), np.uint8)
    depth = np.zeros((H, W), np.float32)
    masks = {}
    wall = _texture(1, H, W + 40)
    img[:] = wall[:, 20 - 3 * t : 20 - 3 * t + W]
    depth[:] = 4.0
    floor = _texture(2, 60, W + 40)
    img[180:] = floor[:, 20 - 8 * t : 20 - 8 * t + W]
    depth[180:] = 1.5
    # (texture seed, x0, y0, w, h, dx per frame, dy per frame, depth)
    objects = {
        "static": (3, 50, 50, 60, 90, int(FB / 2.0), 0, 2.0),
        "mover": (4, 190, 50, 60, 90, 3 + mover_step[0], mover_step[1], 4.0),
    }
    for name, (seed, x0, y0, ow, oh, dx, dy, z) in objects.items():
        x, y = x0 + dx * t, y0 + dy * t
        img[y : y + oh, x : x + ow] = _texture(seed, oh, ow)
        depth[y : y + oh, x : x + ow] = z
        m = np.zeros((H, W), bool)
        m[y : y + oh, x : x + ow] = True
        masks[name] = m
    return img, depth, masks


def _on(mask: np.ndarray, kps: np.ndarray) -> np.ndarray:
    """Keypoints inside ``mask``, rounded as ``keypoint_mobility`` rounds them."""
    x = np.clip(np.round(kps[:, 0]).astype(int), 0, W - 1)
    y = np.clip(np.round(kps[:, 1]).astype(int), 0, H - 1)
    return mask[y, x]


def _pair(mover_step: tuple[int, int] = (0, 7)):
    g0, d0, _ = _render(0, mover_step)
    g1, _, masks = _render(1, mover_step)
    return orb_features(g0, 1500), orb_features(g1, 1500), d0, masks


def test_independent_patch_is_moving_static_person_is_not() -> None:
    f0, f1, _, masks = _pair()
    r = check_motion(f0, f1, np.stack([masks["static"], masks["mover"]]))
    assert r.model == "F" and r.fundamental is not None
    assert r.decided.tolist() == [True, True]
    assert r.moving.tolist() == [False, True]
    assert r.median_px[1] > 3 * r.threshold  # 7 px off its epipolar line
    assert r.threshold >= 1.0


def test_motion_along_epipolar_lines_needs_depth() -> None:
    f0, f1, d0, masks = _pair(mover_step=(6, 0))  # extra 6 px along x: stays on its line
    regions = np.stack([masks["static"], masks["mover"]])
    assert check_motion(f0, f1, regions).moving.tolist() == [False, False]
    r = check_motion(f0, f1, regions, depth_m=d0, camera=CAMERA)
    assert r.model == "PnP" and r.moving.tolist() == [False, True]


def test_still_camera_falls_back_to_homography() -> None:
    g0 = _texture(5, H, W)
    g1 = g0.copy()
    patch = _texture(6, 60, 60)
    g0[100:160, 100:160] = patch
    g1[105:165, 100:160] = patch  # only the patch moves, 5 px down
    m = np.zeros((H, W), bool)
    m[105:165, 100:160] = True
    r = check_motion(orb_features(g0, 1500), orb_features(g1, 1500), m[None])
    assert r.model == "H" and r.moving.tolist() == [True]


def test_epipolar_modes_keep_only_the_mover_dynamic() -> None:
    f0, f1, _, masks = _pair()
    mobility = np.array([1.0], np.float32)  # both are people
    boxes = np.array([[50, 50, 116, 140], [193, 57, 253, 147]], np.float32)
    seg = np.stack([masks["static"], masks["mover"]])
    args = (f1.keypoints, frame_objects(boxes, np.array([0, 0]), seg, (H, W)))
    on_static, on_mover = _on(seg[0], f1.keypoints), _on(seg[1], f1.keypoints)
    plain = process_frame(
        inputs=FrameInputs(*args),
        settings=FrameRules(mobility, "seg", PAPERS.with_values(min_static=10)),
    )
    assert plain.dynamic[on_static].all() and plain.dynamic[on_mover].all()
    for mode in ("semantic+epipolar", "fusion+epipolar"):
        r = process_frame(
            inputs=FrameInputs(*args, descriptors=f1.descriptors, previous=PreviousFrame(f0)),
            settings=FrameRules(mobility, mode, PAPERS.with_values(min_static=10)),
        )
        assert r.checked == [0, 1]
        assert not r.dynamic[on_static].any()
        assert r.dynamic[on_mover].all()
        assert r.mask[masks["mover"]].all() and not r.mask[masks["static"]].any()
        first = process_frame(
            inputs=FrameInputs(*args, descriptors=f1.descriptors),
            settings=FrameRules(mobility, mode, PAPERS.with_values(min_static=10)),
        )
        assert np.array_equal(first.dynamic, plain.dynamic)  # no previous frame: like seg


def test_too_few_points_stay_undecided_and_dynamic() -> None:
    f0, f1, _, _ = _pair()
    tiny = np.zeros((H, W), bool)
    tiny[60:63, 60:63] = True  # a 3×3 px detection on the static person: < 5 matches
    r = check_motion(f0, f1, tiny[None])
    assert not r.decided[0] and not r.moving[0]
    out = process_frame(
        inputs=FrameInputs(
            f1.keypoints,
            frame_objects(np.array([[60, 60, 63, 63]], np.float32), [0], tiny[None], (H, W)),
            descriptors=f1.descriptors,
            previous=PreviousFrame(f0),
        ),
        settings=FrameRules(
            np.array([1.0], np.float32), "semantic+epipolar", PAPERS.with_values(min_static=10)
        ),
    )
    on_tiny = _on(tiny, f1.keypoints)
    assert on_tiny.any() and out.dynamic[on_tiny].all()


def test_distance_and_threshold_formulas() -> None:
    f = np.array([[0, 0, 0], [0, 0, -1], [0, 1, 0]], float)  # pure x translation
    p0 = np.array([[10.0, 20.0], [50.0, 60.0]])
    p1 = np.array([[14.0, 20.0], [50.0, 63.0]])
    assert np.allclose(epipolar_distance(f, p0, p1), [0.0, 3.0])
    d = np.array([0.1, 0.2, 0.3, 0.2, 5.0])
    med, mad = 0.2, 0.1
    assert adaptive_epipolar_threshold(d, k=3.0, floor=0.0) == pytest.approx(med + 3 * 1.4826 * mad)
    assert adaptive_epipolar_threshold(d) == 1.0  # the 1 px floor


def test_bad_input_is_reported() -> None:
    f0, f1, _, masks = _pair()
    with pytest.raises(ValueError, match="regions must be bool"):
        check_motion(f0, f1, masks["mover"])
    with pytest.raises(ValueError, match="descriptors"):
        OrbFeatures(np.zeros((3, 2), np.float32), np.zeros((2, 32), np.uint8))
    with pytest.raises(ValueError, match="descriptors="):
        process_frame(
            inputs=FrameInputs(
                f1.keypoints,
                frame_objects(np.array([[0, 0, 10, 10]]), [0], masks["mover"][None], (H, W)),
                previous=PreviousFrame(f0),
            ),
            settings=FrameRules(np.array([1.0], np.float32), "fusion+epipolar"),
        )
