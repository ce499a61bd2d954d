"""The checks an :class:`~slimseg.deploy.ov_session.OpenVinoSession` runs on its first
:data:`CHECK_FRAMES` frames, one log line each (numpy only).

- :func:`check_precision`: a session asked for bf16 / f16 against the same file at f32, in
  multiples of the export's FP32 limits (raw outputs) or as matched detections (end-to-end).
- :func:`check_int8_kernels`: OpenVINO's INT8 kernels on an INT8 Q/DQ file against the same
  Q/DQ computed as written (in float): on the candidate anchors, the contract's FP16 detection
  rule (same class, box IoU >= 0.9, |score diff| <= 0.02). With OpenVINO 2026.4 on an AMD
  Zen 4 (AVX512-VNNI, no AMX) the kernels keep 97-100 % of the candidates of both targets' files
  (the ``tensorrt`` one given as uint8: :mod:`slimseg.deploy.qdq_unsigned`; as written, 0 %);
  with the ISA capped to AVX2 (``ONEDNN_MAX_CPU_ISA=AVX2``: no VNNI) about half
  (docs/engines.md).
"""

from __future__ import annotations

import logging

import numpy as np

from slimseg.deploy.tolerances import FP32_TOLERANCES, Tolerance

log = logging.getLogger(__name__)

CHECK_FRAMES = 2  # frames checked against the reference compile
MATCH_IOU = 0.9  # a detection matches: same class, box IoU at least this
SCORE_TOL = 0.02  # ... and |score difference| at most this (INT8 kernels check)
CANDIDATE_SCORE = 0.05  # anchors whose best reference score reaches this are checked
INT8_AGREEMENT = 0.9  # candidate anchors the INT8 kernels must keep (measured: 0 or >= 0.97)


def check_precision(
    what: str, frame: int, ref: dict[str, np.ndarray], got: dict[str, np.ndarray], meta: dict
) -> bool:
    """Log how far ``got`` (bf16 / f16) is from ``ref`` (f32) on ``frame``; True if within
    the FP32 limits (raw) or every detection matched with the same ``num_dets`` (end-to-end)."""
    head = f"{what} vs f32 on frame {frame}: "  # what: "m.onnx: OpenVINO (bf16)"
    if "num_dets" in ref:  # rows may change order: detections matched instead
        matched, total = end2end_matches(ref, got)
        ok = matched == total and np.array_equal(ref["num_dets"], got["num_dets"])
        line = (
            f"{head}{matched} of {total} detections matched (same class, box IoU >= "
            f"{MATCH_IOU}); num_dets {ref['num_dets'].tolist()} -> {got['num_dets'].tolist()}"
        )
    else:
        excess, worst = precision_excess(ref, got, len(meta["names"]))
        ok = excess <= 1
        line = f"{head}{excess:.2f}x the export's FP32 limits (worst {worst})"
    if ok:
        log.info(line)
    else:
        log.warning("%s: the contract's parity holds at f32 only", line)
    return ok


def check_int8_kernels(
    what: str,
    frame: int,
    ref: dict[str, np.ndarray],
    got: dict[str, np.ndarray],
    meta: dict,
    precision: str = "f32",
) -> bool:
    """Log how many candidate anchors OpenVINO's INT8 kernels (``got``, their float parts at
    ``precision``) keep of the exact Q/DQ arithmetic at f32 (``ref``) on ``frame``; True when
    at least :data:`INT8_AGREEMENT`."""
    if "output0" not in ref:
        return True
    kept, checked = candidate_agreement(ref["output0"], got["output0"], len(meta["names"]))
    line = (
        f"{what} INT8 kernels vs the file's Q/DQ arithmetic on frame {frame}: {kept} of "
        f"{checked} candidate detections kept"
    )
    if checked and kept < INT8_AGREEMENT * checked:
        why, instead = (
            ("this CPU's INT8 kernels do not compute this file as written (without VNNI they "
             "saturate; docs/engines.md)", "give OpenVINO the FP32 file on this CPU")
            if precision == "f32"
            else (f"its INT8 kernels with {precision} float parts are that far from it",
                  "--backend openvino (f32) keeps the INT8 kernels")
        )  # fmt: skip
        log.warning(
            "%s: %s; running its Q/DQ in float at f32 from now on (right, FP32's speed): %s",
            line,
            why,
            instead,
        )
        return False
    log.info(line)
    return True


def candidate_agreement(ref: np.ndarray, got: np.ndarray, nc: int) -> tuple[int, int]:
    """``(kept, checked)`` over the candidate anchors of ``ref`` (``output0 [B, 4 + nc + nm,
    A]``, best class score >= :data:`CANDIDATE_SCORE`, else its 20 best): same class, box IoU
    >= :data:`MATCH_IOU`, best score within :data:`SCORE_TOL`."""
    kept = checked = 0
    for r, g in zip(ref.astype(np.float64), got.astype(np.float64), strict=True):
        rs, gs = r[4 : 4 + nc].T, g[4 : 4 + nc].T  # [A, nc]
        best = rs.max(1)
        cand = np.flatnonzero(best >= CANDIDATE_SCORE)
        cand = cand if len(cand) else np.argsort(-best)[:20]
        iou = _iou_xywh(r[:4, cand].T, g[:4, cand].T)
        same = rs[cand].argmax(1) == gs[cand].argmax(1)
        close = np.abs(best[cand] - gs[cand].max(1)) <= SCORE_TOL
        kept += int((same & close & (iou >= MATCH_IOU)).sum())
        checked += len(cand)
    return kept, checked


def _iou_xywh(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise IoU of ``cx, cy, w, h`` boxes ``a [N, 4]`` and ``b [N, 4]``."""
    lo = np.maximum(a[:, :2] - a[:, 2:] / 2, b[:, :2] - b[:, 2:] / 2)
    hi = np.minimum(a[:, :2] + a[:, 2:] / 2, b[:, :2] + b[:, 2:] / 2)
    inter = np.clip(hi - lo, 0, None).prod(1)
    union = np.clip(a[:, 2:], 0, None).prod(1) + np.clip(b[:, 2:], 0, None).prod(1) - inter
    return inter / np.maximum(union, 1e-9)


def end2end_matches(ref: dict[str, np.ndarray], got: dict[str, np.ndarray]) -> tuple[int, int]:
    """``(matched, total)``: the valid rows of the end-to-end outputs ``ref`` (``num_dets
    [B]``, ``boxes [B, K, 4]``, ``classes [B, K]``) that a valid row of ``got`` of the same
    class overlaps with IoU >= :data:`MATCH_IOU`."""
    matched = total = 0
    for b, (n_ref, n_got) in enumerate(zip(ref["num_dets"], got["num_dets"], strict=True)):
        rb, rc = ref["boxes"][b, :n_ref], ref["classes"][b, :n_ref]
        gb, gc = got["boxes"][b, :n_got], got["classes"][b, :n_got]
        total += len(rb)
        if not len(rb) or not len(gb):
            continue
        lo, hi = (
            np.maximum(rb[:, None, :2], gb[None, :, :2]),
            np.minimum(rb[:, None, 2:], gb[None, :, 2:]),
        )
        inter = np.clip(hi - lo, 0, None).prod(-1)
        area = lambda x: np.clip(x[:, 2:] - x[:, :2], 0, None).prod(-1)  # noqa: E731
        iou = inter / np.maximum(area(rb)[:, None] + area(gb)[None, :] - inter, 1e-9)
        iou = np.where(rc[:, None] == gc[None, :], iou, 0.0)
        matched += int((iou.max(axis=1) >= MATCH_IOU).sum())
    return matched, total


def _groups(name: str, arr: np.ndarray, nc: int) -> list[tuple[str, str, np.ndarray]]:
    """``(label, tolerance key, part)`` of one output: ``output0``'s box rows, score rows and
    mask coefficients; prototypes, end-to-end boxes / scores / masks, logits as themselves."""
    if name == "output0":
        return [("output0 boxes", "box_px", arr[:, :4]),
                ("output0 scores", "score", arr[:, 4 : 4 + nc]),
                ("output0 mask terms", "mask_terms", arr[:, 4 + nc :])]  # fmt: skip
    key = {"output1": "mask_terms", "masks": "mask_terms", "boxes": "box_px", "scores": "score",
           "logits": "logit"}.get(name)  # fmt: skip
    return [] if key is None else [(name, key, arr)]


def precision_excess(
    ref: dict[str, np.ndarray], got: dict[str, np.ndarray], nc: int
) -> tuple[float, str]:
    """The largest ``|got - ref| / (atol + rtol · |ref|)`` over the float outputs (FP32
    limits per output part, :data:`~slimseg.deploy.tolerances.FP32_TOLERANCES`; ``nc``
    classes in ``output0 [B, 4 + nc + nm, A]``) and a description of that element."""
    best, where = 0.0, "every element equal"
    for name, arr in ref.items():
        for label, key, part in _groups(name, arr, nc):
            other = _groups(name, got[name], nc)
            cand = next(p for lbl, _, p in other if lbl == label)
            ratio, diff = _ratio(part, cand, FP32_TOLERANCES[key])
            if ratio > best:
                best, where = ratio, f"{label} |diff| {diff:.3g}"
    return best, where


def _ratio(ref: np.ndarray, got: np.ndarray, tol: Tolerance) -> tuple[float, float]:
    if ref.size == 0 or ref.shape != got.shape:
        return 0.0, 0.0
    r, g = ref.astype(np.float64), got.astype(np.float64)
    diff = np.abs(g - r)
    ratio = diff / (tol.atol + tol.rtol * np.abs(r))
    i = int(np.nanargmax(ratio)) if np.isfinite(ratio).any() else 0
    return float(ratio.flat[i]), float(diff.flat[i])
