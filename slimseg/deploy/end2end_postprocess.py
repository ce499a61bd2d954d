"""End-to-end export outputs → :class:`~slimseg.detections.Prediction` per frame (numpy, no torch).

An end-to-end export (``slimseg export --end2end``, :mod:`slimseg.deploy.end2end_graph`) does
the decoding, class-aware NMS and top-``max_det`` inside the graph; what is left for a runtime
is the letterbox's inverse and the contract's mask steps 4–5 from the graph's probabilities
(:func:`~slimseg.ops.masks_numpy.masks_from_probs`), the same code the raw path runs after its
own mask product, so both give the same masks for the same detections.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from slimseg.deploy.predict_postprocess import frame_prediction
from slimseg.detections import Prediction
from slimseg.errors import SlimsegError
from slimseg.ops.letterbox import LetterboxParams
from slimseg.ops.masks_numpy import masks_from_probs

log = logging.getLogger(__name__)

#: the outputs of an end-to-end export, in graph order (``masks`` only for segmenters)
END2END_OUTPUTS = ("num_dets", "boxes", "scores", "classes", "masks")


def is_end2end(meta: dict[str, Any]) -> bool:
    """The export's metadata describes an end-to-end graph (``end2end`` key)."""
    return isinstance(meta.get("end2end"), dict)


_warned: set[tuple] = set()


def end2end_limits(meta: dict[str, Any], conf: float, iou: float, where: str) -> None:
    """Log a warning (once per model and request) when a request asks for what the graph's
    baked-in NMS cannot give: a ``conf`` below the graph's or another ``iou`` (the graph's
    values apply). A ``max_det`` above the graph's is bounded by its rows silently."""
    e2e = meta["end2end"]
    key = (where, conf, iou)
    if (conf < float(e2e["conf"]) or iou != float(e2e["iou"])) and key not in _warned:
        _warned.add(key)
        log.warning(
            "%s: end-to-end graph with conf %s, iou %s inside; asked for conf %s, iou %s: the "
            "graph's values apply",
            where, e2e["conf"], e2e["iou"], conf, iou,
        )  # fmt: skip


def end2end_predictions(
    outs: dict[str, np.ndarray],
    metas: Sequence[dict],
    names: list[str],
    mobility: list[float],
    conf: float,
    max_det: int,
) -> list[Prediction]:
    """``outs``: ``num_dets [B]``, ``boxes [B, K, 4]`` (input pixels), ``scores [B, K]``,
    ``classes [B, K]`` and optionally ``masks [B, K, Hp, Wp]`` → one :class:`Prediction` per
    frame of ``metas``: the valid rows with ``score > conf`` (float32), at most ``max_det``."""
    missing = [n for n in END2END_OUTPUTS[:4] if n not in outs]
    if missing:
        raise SlimsegError(f"end-to-end model: outputs {', '.join(missing)} missing")
    nc = len(names)
    out = []
    for i, meta in enumerate(metas):
        p: LetterboxParams = meta["letterbox"]
        h, w = (int(v) for v in meta["orig_shape"])
        n = int(outs["num_dets"][i])
        scores = np.asarray(outs["scores"][i, :n], np.float32)
        idx = np.flatnonzero(scores > np.float32(conf))[:max_det]
        classes = np.asarray(outs["classes"][i, idx], np.int64)
        if len(classes) and (classes.min() < 0 or classes.max() >= nc):
            raise SlimsegError(f"end-to-end model: class ids outside 0..{nc - 1}")
        boxes = np.asarray(outs["boxes"][i, idx], np.float32).reshape(-1, 4)
        masks = None
        if "masks" in outs:
            probs = np.asarray(outs["masks"][i, idx], np.float32)
            masks = masks_from_probs(probs, boxes, p, (h, w))
        out.append(frame_prediction(boxes, scores[idx], classes, masks, names, mobility, p, (h, w)))
    return out
