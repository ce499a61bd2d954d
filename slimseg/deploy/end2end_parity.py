"""The end-to-end export's gate: its instances equal ``slimseg predict``'s on the raw graph.

Both files run in onnxruntime through :class:`~slimseg.deploy.predictor.Predictor` on
synthetic frames (:func:`gate_frames`, 4:3 so the letterbox pads): the raw graph with the
numpy post-processing (:mod:`slimseg.deploy.predict_postprocess`), the end-to-end graph with
its NMS inside (:mod:`slimseg.deploy.end2end_postprocess`). Each of the raw path's detections
(score above :data:`GATE_CONF`) must find an end-to-end detection of its class with box IoU ≥
:data:`MATCH_IOU`, ``|Δscore|`` ≤ :data:`SCORE_TOL` and mask IoU ≥ :data:`MATCH_IOU`; at
least :data:`MATCH_FRACTION` of them must (:data:`FP16_MATCH_FRACTION` for an FP16 end-to-end
graph against the FP32 one, ``tests/deploy/test_end2end.py``). A ``--dynamic`` export is also run at
batch 2. ``export/CONTRACT.md`` states the numbers; this module is their one home.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slimseg.data.synth.scene import STREAM_VAL, render_image
from slimseg.deploy.parity import ExportParityError
from slimseg.deploy.predictor import Predictor
from slimseg.detections import Prediction
from slimseg.ops.nms_numpy import PREDICT_CONF

GATE_CONF = PREDICT_CONF  # detections compared: score > 0.25
MATCH_IOU = 0.9  # box IoU and mask IoU of a matched pair
SCORE_TOL = 0.02  # |score difference| of a matched pair
MATCH_FRACTION = 0.95  # end-to-end vs the raw path, same precision
FP16_MATCH_FRACTION = 0.90  # FP16 end-to-end vs FP32 end-to-end
GATE_FRAMES = 4


def gate_frames(imgsz: tuple[int, int], count: int = GATE_FRAMES) -> list[np.ndarray]:
    """``count`` synthetic RGB ``uint8 [3W/4, W, 3]`` frames (W = the input width; the
    validation stream of seed 0)."""
    w = int(imgsz[1])
    return [render_image(0, i, w, STREAM_VAL).rgb[: w * 3 // 4] for i in range(count)]


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU ``[N, M]`` of xyxy boxes ``a [N, 4]`` and ``b [M, 4]`` (float64)."""
    a, b = a.astype(np.float64), b.astype(np.float64)
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.clip(rb - lt, 0, None).prod(-1)
    area_a, area_b = (a[:, 2:] - a[:, :2]).prod(-1), (b[:, 2:] - b[:, :2]).prod(-1)
    return inter / np.maximum(area_a[:, None] + area_b[None] - inter, 1e-9)


def _mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union


def match_predictions(refs: list[Prediction], gots: list[Prediction]) -> dict[str, float]:
    """Per frame, each detection of ``refs`` (by decreasing score) takes the unmatched
    detection of ``gots`` of its class with the highest box IoU; counted as matched when box
    IoU ≥ :data:`MATCH_IOU`, ``|Δscore|`` ≤ :data:`SCORE_TOL` and (masks) mask IoU ≥
    :data:`MATCH_IOU`. Returns ``detections``, ``matched``, ``fraction`` (1 without
    detections), ``extra`` (unmatched detections of ``gots``) and the worst ``min_box_iou``,
    ``max_score_diff``, ``min_mask_iou`` over matched pairs."""
    total = matched = extra = 0
    worst = {"min_box_iou": 1.0, "max_score_diff": 0.0, "min_mask_iou": 1.0}
    for ref, got in zip(refs, gots, strict=True):
        total += len(ref.scores)
        iou = box_iou(ref.boxes, got.boxes)
        taken = np.zeros(len(got.scores), bool)
        for i in range(len(ref.scores)):
            same = (got.classes == ref.classes[i]) & ~taken
            if not same.any():
                continue
            j = int(np.argmax(np.where(same, iou[i], -1.0)))
            diff = abs(float(ref.scores[i]) - float(got.scores[j]))
            m_iou = 1.0
            if ref.masks is not None and got.masks is not None:
                m_iou = _mask_iou(ref.masks[i], got.masks[j])
            if iou[i, j] >= MATCH_IOU and diff <= SCORE_TOL and m_iou >= MATCH_IOU:
                taken[j] = True
                matched += 1
                worst["min_box_iou"] = min(worst["min_box_iou"], float(iou[i, j]))
                worst["max_score_diff"] = max(worst["max_score_diff"], diff)
                worst["min_mask_iou"] = min(worst["min_mask_iou"], m_iou)
        extra += int((~taken).sum())
    fraction = matched / total if total else 1.0
    return {"detections": total, "matched": matched, "fraction": fraction, "extra": extra, **worst}


def verify_end2end(
    raw_path: Path, e2e_path: Path, imgsz: tuple[int, int], dynamic: bool
) -> dict[str, float]:
    """Gate the end-to-end graph at ``e2e_path`` on the raw graph at ``raw_path`` (module
    docstring); returns ``{"end2end/<key>": value}`` (``end2end_batch2/...`` too when
    ``dynamic``); :class:`ExportParityError` when fewer than :data:`MATCH_FRACTION` match."""
    ref = Predictor.from_path(raw_path, threads=1)
    got = Predictor.from_path(e2e_path, threads=1)
    frames = gate_frames(imgsz)
    e2e = got.metadata["end2end"]
    conf, iou, k = max(GATE_CONF, float(e2e["conf"])), float(e2e["iou"]), int(e2e["max_det"])
    refs = [ref.predict(f, conf, iou, k) for f in frames]
    runs = {"end2end": [got.predict(f, conf, iou, k) for f in frames]}
    if dynamic:
        runs["end2end_batch2"] = got.predict_batch(frames, conf, iou, k)
    results: dict[str, float] = {}
    for tag, gots in runs.items():
        stats = match_predictions(refs, gots)
        if stats["fraction"] < MATCH_FRACTION:
            raise ExportParityError(
                f"end-to-end graph ({tag}) kept {stats['matched']} of the raw path's "
                f"{stats['detections']} detections on {len(frames)} synthetic frames "
                f"({stats['fraction']:.1%} < {MATCH_FRACTION:.0%}; match: same class, box and "
                f"mask IoU >= {MATCH_IOU}, |score diff| <= {SCORE_TOL})"
            )
        results.update({f"{tag}/{key}": float(v) for key, v in stats.items()})
    return results
