"""The runtime's numpy post-processing (``slimseg.deploy.predict_postprocess``) against the torch
path validation runs (``slimseg.eval.postprocess.outputs_to_frame_detections``): the same
detections in the same order, bit for bit, and the same mask pixels except where a pixel's
value lies within float32 rounding of the 0.5 threshold (BLAS and ``exp`` round the last bit
differently from torch's); the same class maps; NMS on ties and on the per-class path."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import batchnorm_from, disc_scene, open_class_bias

from slimseg.deploy.predict_postprocess import instance_predictions, semantic_class_map
from slimseg.deploy.preprocess import preprocess_frame
from slimseg.eval.postprocess import outputs_to_frame_detections
from slimseg.models.registry import build_model
from slimseg.ops.letterbox import letterbox_params
from slimseg.ops.masks_numpy import frame_masks
from slimseg.ops.nms import non_max_suppression
from slimseg.ops.nms_numpy import PER_CLASS_ABOVE, nms_rows
from slimseg.ops.semantic import logits_to_frame

NAMES = ["a", "b", "c"]
IMGSZ = 128
# a mask pixel may flip only where its value is this close to 0.5 (a few float32 steps)
NEAR_HALF = 2e-6


def _model(name: str) -> torch.nn.Module:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    net = build_model(name, num_classes=len(NAMES))
    frames = np.stack([disc_scene(rng, IMGSZ, IMGSZ, 6) for _ in range(4)])
    batchnorm_from(net, torch.from_numpy(frames).permute(0, 3, 1, 2))
    return open_class_bias(net)


@pytest.fixture(scope="module", params=["yolov8n-seg", "yolov8n-seg-hr"])
def outputs(request) -> list[tuple[np.ndarray, np.ndarray, dict]]:
    """``(pred, proto, meta)`` of frames the letterbox shrinks (240x320, by 0.4), leaves
    (96x128) and enlarges (48x64, by 2)."""
    net = _model(request.param).eval()
    rng = np.random.default_rng(1)
    out = []
    for h, w in ((240, 320), (96, 128), (48, 64)):
        rgb = (disc_scene(rng, h, w, 8) * 255).astype(np.uint8)
        x, meta = preprocess_frame(rgb, (IMGSZ, IMGSZ))
        with torch.no_grad():
            pred, proto = net(torch.from_numpy(x))
        out.append((pred.numpy(), proto.numpy(), meta))
    return out


@pytest.mark.parametrize("conf", [0.001, 0.3])
def test_numpy_postprocess_keeps_the_torch_detections_and_mask_pixels(outputs, conf) -> None:
    flipped = total = 0
    for pred, proto, meta in outputs:
        ref = outputs_to_frame_detections(
            torch.from_numpy(pred), torch.from_numpy(proto), [meta], "yolov8", 3, conf, 0.7, 300
        )[0]
        (got,) = instance_predictions(
            pred, proto, [meta], NAMES, [1.0, 0.5, 0.0], "yolov8", conf, 0.7, 300
        )
        assert len(ref) > 0 and len(ref) == len(got)
        np.testing.assert_array_equal(got.boxes, ref.boxes)
        np.testing.assert_array_equal(got.scores, ref.scores)
        np.testing.assert_array_equal(got.classes, ref.classes)
        assert got.masks.shape == ref.masks.shape and got.masks.dtype == bool
        differ = got.masks != ref.masks
        if differ.any():  # only pixels on the threshold's edge
            boxes, _, _, coeffs = nms_rows(pred[0], 3, conf=conf)
            values = frame_masks(
                coeffs, proto[0], boxes, meta["letterbox"], meta["orig_shape"], threshold=None
            )
            assert np.abs(values[differ] - 0.5).max() < NEAR_HALF
        flipped += int(differ.sum())
        total += int(ref.masks.sum())
    assert total > 1000  # the frames hold masks to compare
    assert flipped <= total * 1e-4


def test_mask_values_threshold_to_the_masks(outputs) -> None:
    pred, proto, meta = outputs[0]
    boxes, _, _, coeffs = nms_rows(pred[0], 3, conf=0.001)
    p, hw = meta["letterbox"], meta["orig_shape"]
    values = frame_masks(coeffs, proto[0], boxes, p, hw, threshold=None)
    masks = frame_masks(coeffs, proto[0], boxes, p, hw)
    assert values.dtype == np.float32 and masks.any()
    np.testing.assert_array_equal(values > 0.5, masks)


def _rows(rng: np.random.Generator, anchors: int, nc: int, levels: int | None) -> np.ndarray:
    """Random rows ``[4 + nc + 2, A]``: clustered boxes (overlaps to suppress); scores on
    ``levels`` values (ties) or continuous (``None``)."""
    cxy = rng.uniform(0, 300, (2, anchors)).round(-1) + rng.normal(0, 3, (2, anchors))
    wh = rng.uniform(5, 80, (2, anchors))
    if levels is None:
        scores = rng.uniform(0, 1, (nc, anchors))
    else:
        scores = rng.integers(1, levels, (nc, anchors)) / levels
    coeffs = rng.normal(size=(2, anchors))
    return np.concatenate([cxy, wh, scores, coeffs]).astype(np.float32)


def _both(
    rows: np.ndarray, agnostic: bool, max_det: int = 300
) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    (ref,) = non_max_suppression(
        torch.from_numpy(rows[None]), 4, 0.3, agnostic=agnostic, max_det=max_det
    )
    want = (ref.boxes.numpy(), ref.scores.numpy(), ref.classes.numpy(), ref.coeffs.numpy())
    assert len(ref) > 10
    return nms_rows(rows, 4, 0.3, agnostic=agnostic, max_det=max_det), want


@pytest.mark.parametrize(("anchors", "levels"), [(600, 20), (2 * PER_CLASS_ABOVE + 500, None)])
def test_nms_matches_torchvision(anchors, levels) -> None:
    """Up to 1000 candidates (one shifted NMS, stable order: ties too) and beyond (one NMS
    per class; continuous scores): the same detections in the same order."""
    rng = np.random.default_rng(anchors)
    rows = _rows(rng, anchors, 4, levels)
    for agnostic in (False, True):
        got, want = _both(rows, agnostic)
        for g, w in zip(got, want, strict=True):
            np.testing.assert_array_equal(g, w)


def test_nms_beyond_1000_candidates_with_tied_scores_keeps_the_same_set() -> None:
    """The one known difference: above 1000 candidates torchvision sorts the survivors of
    its per-class NMS with an unstable sort, so detections of equal score may come in
    another order (the numpy path keeps anchor order), and a ``max_det`` cut through a tie
    may keep others; below the cut the detections kept are the same."""
    rows = _rows(np.random.default_rng(3), 2 * PER_CLASS_ABOVE + 500, 4, 20)
    got, want = _both(rows, False, max_det=len(rows[0]))
    np.testing.assert_array_equal(got[1], want[1])  # scores: the same sequence
    key = lambda d: sorted(map(tuple, np.column_stack([d[0], d[1], d[2]]).tolist()))  # noqa: E731
    assert key(got) == key(want)


def test_semantic_class_map_matches_torch() -> None:
    rng = np.random.default_rng(2)
    logits = rng.normal(size=(4, IMGSZ, IMGSZ)).astype(np.float32)
    for h, w in ((240, 320), (96, 128), (50, 70)):
        p = letterbox_params(h, w, IMGSZ, IMGSZ)
        ref = logits_to_frame(torch.from_numpy(logits), p, (h, w)).numpy()
        np.testing.assert_array_equal(semantic_class_map(logits, p, (h, w)), ref)
