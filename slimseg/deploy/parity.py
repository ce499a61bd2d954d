"""Export parity: the tolerances and the onnxruntime-vs-fused-torch comparisons.

FP32 (and the FP32 logits of semantic models): every element within
``atol + rtol · |torch|`` of the fused torch model, :func:`numpy.allclose`'s rule, with
``atol``/``rtol`` per output (:data:`FP32_TOLERANCES`). Float32 kernels that sum in another
order (onnxruntime vs torch, one CPU vs another) differ by ~1e-5 of the magnitude of what they
sum, so a fixed absolute limit refuses correct graphs whose outputs are large; ``rtol`` covers
large elements, ``atol`` the elements near zero in a tensor whose other elements are large.
FP16 is judged on the detections instead (:func:`check_fp16_parity`: box IoU, which is
relative to the box size, and scores, which are probabilities in [0, 1]); semantic FP16 on the
class map. ``export/CONTRACT.md`` states the numbers; this module is their one home.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from slimseg.deploy.ort_session import cpu_session
from slimseg.deploy.tolerances import (
    FP32_LOGIT_TOL,
    FP32_TOLERANCES,
    Tolerance,
)
from slimseg.errors import SlimsegError
from slimseg.models.base import ZooModel
from slimseg.models.registry import detection_rows
from slimseg.ops.nms import non_max_suppression


class ExportParityError(SlimsegError):
    """The exported graph does not compute what the fused torch model computes."""


FP16_CANDIDATE_SCORE = 0.05  # anchors whose best FP32 score reaches this are checked
FP16_MATCH_IOU = 0.9
FP16_SCORE_TOL = 0.02
FP16_CLASS_AGREEMENT = 0.99  # semantic FP16: fraction of pixels with the FP32 argmax class


@dataclass(frozen=True)
class Mismatch:
    """The element of one output that exceeds its tolerance the most."""

    output: str  # e.g. "output1 prototypes (mask_terms)"
    index: tuple[int, ...]
    onnx: float
    torch: float
    tol: Tolerance

    @property
    def limit(self) -> float:
        """``atol + rtol · |torch|`` at this element."""
        return self.tol.atol + self.tol.rtol * abs(self.torch)

    @property
    def excess(self) -> float:
        return abs(self.onnx - self.torch) - self.limit

    def __str__(self) -> str:
        where = ", ".join(map(str, self.index))
        return (
            f"{self.output} at [{where}]: onnx {self.onnx:.6g} vs torch {self.torch:.6g}, "
            f"|diff| {abs(self.onnx - self.torch):.3g} > {self.tol} = {self.limit:.3g} "
            f"(excess {self.excess:.3g})"
        )


def worst_mismatch(name: str, ref: np.ndarray, got: np.ndarray, tol: Tolerance) -> Mismatch | None:
    """The element of ``got`` farthest outside ``tol`` around ``ref`` (same shape, any), or
    ``None`` when all are within. NaN counts as outside; equal infinities as within."""
    ref64, got64 = ref.astype(np.float64), got.astype(np.float64)
    with np.errstate(invalid="ignore"):
        excess = np.abs(got64 - ref64) - (tol.atol + tol.rtol * np.abs(ref64))
    excess = np.where(ref64 == got64, -np.inf, excess)
    excess = np.where(np.isnan(excess), np.inf, excess)
    if excess.size == 0 or excess.max() <= 0:
        return None
    index = np.unravel_index(int(excess.argmax()), excess.shape)
    return Mismatch(
        name, tuple(int(i) for i in index), float(got64[index]), float(ref64[index]), tol
    )


def _max_abs(ref: np.ndarray, got: np.ndarray) -> float:
    return float(np.abs(ref.astype(np.float64) - got).max(initial=0.0))


def _rows(model: ZooModel, pred: np.ndarray) -> torch.Tensor:
    return detection_rows(model.spec.family, torch.from_numpy(pred).float())


def _fp32_groups(model: ZooModel, outs: list[np.ndarray]) -> list[tuple[str, str, np.ndarray]]:
    """``(key, output name, array)`` compared under ``FP32_TOLERANCES[key]``: boxes
    ``[B, 4, A]``, scores ``[B, nc, A]``, mask coefficients ``[B, nm, A]`` and prototypes
    ``[B, nm, H/s, W/s]`` (both under ``mask_terms``)."""
    nc = model.num_classes
    rows = _rows(model, outs[0]).numpy()
    darknet = rows.shape[1] != outs[0].shape[1]  # objectness folded into the class scores
    groups = [
        ("box_px", "output0 boxes", rows[:, :4]),
        (
            "score",
            "output0 objectness x class" if darknet else "output0 class scores",
            rows[:, 4 : 4 + nc],
        ),
    ]
    if rows.shape[1] > 4 + nc:
        groups.append(("mask_terms", "output0 mask coefficients", rows[:, 4 + nc :]))
    groups += [("mask_terms", f"output{k} prototypes", o) for k, o in enumerate(outs[1:], 1)]
    return groups


def check_fp32_parity(model: ZooModel, ref: list[np.ndarray], got: list[np.ndarray]) -> dict:
    """Compare a detector's ONNX outputs ``got`` with torch's ``ref`` (``output0 [B, C, A]``,
    optionally ``output1 [B, nm, H/s, W/s]``) under :data:`FP32_TOLERANCES`. Returns the max
    abs differences ``box_px``, ``score`` and (segmenters) ``mask_terms``; raises
    :class:`ExportParityError` naming each failing output's worst element."""
    diffs: dict[str, float] = {}
    bad: list[str] = []
    for (key, name, r), (_, _, g) in zip(
        _fp32_groups(model, ref), _fp32_groups(model, got), strict=True
    ):
        diffs[key] = max(diffs.get(key, 0.0), _max_abs(r, g))
        if (m := worst_mismatch(f"{name} ({key})", r, g, FP32_TOLERANCES[key])) is not None:
            bad.append(str(m))
    if bad:
        raise ExportParityError("FP32 ONNX differs from the fused torch model: " + "; ".join(bad))
    return diffs


def check_semantic_parity(
    model: nn.Module, ref: list[np.ndarray], got: list[np.ndarray], half: bool = False
) -> dict:
    """Semantic models, logits ``[B, nc + 1, H, W]``: max abs logit difference and the
    fraction of pixels whose argmax class agrees. FP32: logits within ``FP32_LOGIT_TOL`` (so
    the class maps agree except at exact ties); FP16: at least ``FP16_CLASS_AGREEMENT`` of the
    pixels keep their class."""
    r, g = ref[0], got[0]
    if r.shape != g.shape:
        raise ExportParityError(f"ONNX logits {g.shape} differ from torch's {r.shape}")
    result = {
        "logit": _max_abs(r, g),
        "class_agreement": float((r.argmax(1) == g.argmax(1)).mean()),
    }
    if half and result["class_agreement"] < FP16_CLASS_AGREEMENT:
        raise ExportParityError(
            f"FP16 ONNX changed the class of {1 - result['class_agreement']:.2%} of the pixels "
            f"(at most {1 - FP16_CLASS_AGREEMENT:.0%} allowed)"
        )
    if not half and (m := worst_mismatch("logits (logit)", r, g, FP32_LOGIT_TOL)) is not None:
        raise ExportParityError(f"FP32 ONNX differs from the fused torch model: {m}")
    return result


def _iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.clip(rb - lt, 0, None).prod(-1)
    area_a = (a[:, 2:] - a[:, :2]).prod(-1)
    area_b = (b[:, 2:] - b[:, :2]).prod(-1)
    return inter / (area_a[:, None] + area_b[None] - inter + 1e-9)


def detection_agreement(
    model: nn.Module, ref: list[np.ndarray], got: list[np.ndarray], top: int = 20
) -> dict:
    """How closely ``got`` (an FP16 or INT8 graph's outputs) keeps the detections of ``ref``
    (FP32) on one input (``output0 [1, C, A]``): on every candidate anchor of ``ref`` (best
    class score ≥ ``FP16_CANDIDATE_SCORE``, or the ``top`` best), the box IoU, the best-score
    difference and whether the class is the same (or two classes are within
    ``FP16_SCORE_TOL``). Checked per anchor, before NMS, so near-tied overlapping boxes cannot
    swap survivors. Returns ``checked``, ``matched`` (IoU ≥ ``FP16_MATCH_IOU``, score within
    ``FP16_SCORE_TOL``, same class), ``min_iou``, ``max_score_diff`` and, when both keep NMS
    survivors at ``FP16_CANDIDATE_SCORE``, the fraction of ``ref``'s survivors matched
    (``nms_matched``)."""
    nc = model.num_classes
    r = _rows(model, ref[0])[0].numpy().T  # [A, 4 + nc (+ ...)]
    g = _rows(model, got[0])[0].numpy().T
    r_scores, g_scores = r[:, 4 : 4 + nc], g[:, 4 : 4 + nc]
    best = r_scores.max(1)
    candidates = np.flatnonzero(best >= FP16_CANDIDATE_SCORE)
    if len(candidates) == 0:
        candidates = np.argsort(-best)[:top]
    xyxy = lambda b: np.concatenate([b[:, :2] - b[:, 2:4] / 2, b[:, :2] + b[:, 2:4] / 2], 1)  # noqa: E731
    rb, gb = xyxy(r[candidates, :4]), xyxy(g[candidates, :4])
    iou = np.diag(_iou_matrix(rb, gb))
    score_diff = np.abs(best[candidates] - g_scores[candidates].max(1))
    top2 = np.sort(r_scores[candidates], 1)[:, -2:] if nc > 1 else None
    tied = (top2[:, 1] - top2[:, 0] <= FP16_SCORE_TOL) if top2 is not None else False
    same_class = (r_scores[candidates].argmax(1) == g_scores[candidates].argmax(1)) | tied
    ok = (iou >= FP16_MATCH_IOU) & (score_diff <= FP16_SCORE_TOL) & same_class
    result = {
        "checked": len(candidates),
        "matched": int(ok.sum()),
        "min_iou": float(iou.min()),
        "max_score_diff": float(score_diff.max()),
    }
    conf = FP16_CANDIDATE_SCORE
    d_ref = non_max_suppression(_rows(model, ref[0]), nc, conf=conf, max_det=300)[0]
    d_got = non_max_suppression(_rows(model, got[0]), nc, conf=conf, max_det=300)[0]
    if len(d_ref) and len(d_got):
        m = _iou_matrix(d_ref.boxes.numpy(), d_got.boxes.numpy()) >= FP16_MATCH_IOU
        m &= (d_ref.classes[:, None] == d_got.classes[None, :]).numpy()
        result["nms_matched"] = float(m.any(1).mean())
    return result


def check_fp16_parity(
    model: nn.Module, ref: list[np.ndarray], got: list[np.ndarray], top: int = 20
) -> dict:
    """FP16 keeps the detections: every candidate anchor of the FP32 model matches
    (:func:`detection_agreement`: IoU ≥ 0.9, score within 0.02, same class); raises
    :class:`ExportParityError` otherwise."""
    result = detection_agreement(model, ref, got, top)
    bad = result["checked"] - result["matched"]
    if bad:
        raise ExportParityError(
            f"FP16 ONNX changed {bad} of {result['checked']} detections (same class, "
            f"IoU >= {FP16_MATCH_IOU}, |score diff| <= {FP16_SCORE_TOL} required; min IoU "
            f"{result['min_iou']:.3f}, max score diff {result['max_score_diff']:.3g})"
        )
    return result


def parity_inputs(imgsz: tuple[int, int], seed: int = 0) -> list[np.ndarray]:
    """Two inputs ``[1, 3, H, W]`` in [0, 1]: uniform noise, and smooth blobs on a gradient
    (closer to a real frame, so scores and masks are not all saturated)."""
    h, w = imgsz
    rng = np.random.default_rng(seed)
    noise = rng.random((1, 3, h, w), dtype=np.float32)
    yy, xx = np.mgrid[:h, :w].astype(np.float32)
    scene = np.stack([xx / w, yy / h, 0.5 * np.ones_like(xx)])
    for _ in range(6):
        cx, cy, r = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(8, min(h, w) / 3)
        blob = ((xx - cx) ** 2 + (yy - cy) ** 2) < r**2
        scene[:, blob] = rng.random(3, dtype=np.float32)[:, None]
    return [noise, scene[None].astype(np.float32)]


def second_size(imgsz: tuple[int, int]) -> tuple[int, int]:
    """The other input size a ``--dynamic`` export is checked at: 32 px taller, 64 px wider
    (non-square, so a swapped H/W axis shows)."""
    return imgsz[0] + 32, imgsz[1] + 64


def _checked_inputs(imgsz: tuple[int, int], dynamic: bool) -> list[tuple[str, np.ndarray]]:
    """``(tag, input [B, 3, H, W])``: the two parity inputs; for dynamic exports also both in
    one batch of 2 and a scene at :func:`second_size`."""
    first = parity_inputs(imgsz)
    inputs = [(f"input{k}", x) for k, x in enumerate(first)]
    if dynamic:
        h, w = second_size(imgsz)
        inputs.append(("batch2", np.concatenate(first)))
        inputs.append((f"size{h}x{w}", parity_inputs((h, w), seed=1)[1]))
    return inputs


def _as_arrays(out: object) -> list[np.ndarray]:
    items = out if isinstance(out, tuple) else (out,)
    return [t.detach().float().numpy() for t in items]


def _compare(
    fused: nn.Module, ref: list[np.ndarray], got: list[np.ndarray], half: bool
) -> dict[str, float]:
    """One input's outputs (batch ``B``) under the rule for ``fused``'s task and precision."""
    if fused.spec.task == "semantic":
        return check_semantic_parity(fused, ref, got, half)
    if not half:
        return check_fp32_parity(fused, ref, got)
    # per image: the detection check reads one image's rows
    per = [
        check_fp16_parity(fused, [r[b : b + 1] for r in ref], [g[b : b + 1] for g in got])
        for b in range(len(ref[0]))
    ]
    checked: dict[str, float] = {k: sum(p[k] for p in per) for k in ("checked", "matched")}
    checked["min_iou"] = min(p["min_iou"] for p in per)
    checked["max_score_diff"] = max(p["max_score_diff"] for p in per)
    return checked


def verify_parity(
    fused: nn.Module, path: Path, imgsz: tuple[int, int], half: bool
) -> dict[str, float]:
    """Run onnxruntime on the graph at ``path`` and the fused torch model on the parity inputs
    ``[1, 3, H, W]`` (a graph with a dynamic input shape also at batch 2 and a second H×W);
    every output is compared. Returns ``{"<input tag>/<key>": value}``; raises
    :class:`ExportParityError` (naming the input) on disagreement."""
    session = cpu_session(path)
    dynamic = not all(isinstance(d, int) for d in session.get_inputs()[0].shape)
    results: dict[str, float] = {}
    for tag, x in _checked_inputs(imgsz, dynamic):
        with torch.no_grad():
            ref = _as_arrays(fused(torch.from_numpy(x)))
        feed = x.astype(np.float16) if half else x
        got = [o.astype(np.float32) for o in session.run(None, {"images": feed})]
        shapes = [r.shape for r in ref], [g.shape for g in got]
        if shapes[0] != shapes[1]:
            raise ExportParityError(
                f"ONNX output shapes {shapes[1]} differ from torch's {shapes[0]} ({tag})"
            )
        try:
            checked = _compare(fused, ref, got, half)
        except ExportParityError as exc:
            raise ExportParityError(f"{exc} ({tag}, input {list(x.shape)})") from None
        for key, value in checked.items():
            results[f"{tag}/{key}"] = value
    return results
