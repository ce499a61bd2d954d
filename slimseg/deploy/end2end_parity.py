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

A model that gives fewer than :data:`MIN_INSTANCES` detections there (an untrained one gives
none, and the gate would check nothing) is also gated through a twin of its end-to-end graph
baked at :func:`low_gate_conf`, so NMS and the mask product are compared on at least
:data:`MIN_INSTANCES` instances (``end2end_low/...`` in the report). Not for an FP16 export:
an untrained model's scores (about 1e-4) lie below what FP16 resolves, and the two paths rank
them differently.
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
MIN_INSTANCES = 50  # detections the gate compares at least (an untrained model: at a low conf)
LOW_CONF_FLOOR = 1e-6  # the lowest score the gate looks for them at
LOW_CONF_MARGIN = 0.999  # the low conf sits this far below the MIN_INSTANCES-th best score


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


def low_gate_conf(raw_path: Path, imgsz: tuple[int, int], iou: float, max_det: int) -> float:
    """The conf at which the raw graph at ``raw_path`` gives :data:`MIN_INSTANCES` detections on
    the gate frames (as many as ``max_det`` allows): just below the score of the
    ``MIN_INSTANCES``-th best, found at :data:`LOW_CONF_FLOOR`. Greedy NMS keeps the same boxes
    above a threshold whatever lies below it, so both paths agree at this conf as at any."""
    ref = Predictor.from_path(raw_path, threads=1)
    scores = np.sort(np.concatenate([ref.predict(f, LOW_CONF_FLOOR, iou, max_det).scores
                                     for f in gate_frames(imgsz)]))[::-1]  # fmt: skip
    if len(scores) == 0:
        return LOW_CONF_FLOOR
    return max(float(scores[min(MIN_INSTANCES, len(scores)) - 1]) * LOW_CONF_MARGIN,
               LOW_CONF_FLOOR)  # fmt: skip


def verify_end2end(
    raw_path: Path,
    e2e_path: Path,
    imgsz: tuple[int, int],
    dynamic: bool,
    conf: float | None = None,
    tag: str = "end2end",
) -> dict[str, float]:
    """Gate the end-to-end graph at ``e2e_path`` on the raw graph at ``raw_path`` (module
    docstring) at ``conf`` (None: :data:`GATE_CONF`, or the graph's own if higher); returns
    ``{"<tag>/<key>": value}`` (``<tag>_batch2/...`` too when ``dynamic``);
    :class:`ExportParityError` when fewer than :data:`MATCH_FRACTION` match."""
    ref = Predictor.from_path(raw_path, threads=1)
    got = Predictor.from_path(e2e_path, threads=1)
    frames = gate_frames(imgsz)
    e2e = got.metadata["end2end"]
    iou, k = float(e2e["iou"]), int(e2e["max_det"])
    conf = max(GATE_CONF, float(e2e["conf"])) if conf is None else conf
    refs = [ref.predict(f, conf, iou, k) for f in frames]
    runs = {tag: [got.predict(f, conf, iou, k) for f in frames]}
    if dynamic:
        runs[f"{tag}_batch2"] = got.predict_batch(frames, conf, iou, k)
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
