"""ONNX export with a verified parity check: nothing reaches its final path unverified.

Pipeline: eval model → fuse (Conv+BN, RepConv) → ``torch.onnx.export`` (opset ≥ 17, TorchScript
exporter: a plain static graph) → onnx checker + shape inference → onnxslim → FP16 conversion
(``--half``: FP16 weights, compute, input and outputs) → metadata → parity against the fused
torch model on two inputs with onnxruntime → rename into place, plus a ``NAME.json`` sidecar.
"""

from __future__ import annotations

import json
import os
import tempfile
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from slimseg.deploy.metadata import build_metadata, to_metadata_props
from slimseg.deploy.ort_session import cpu_session
from slimseg.errors import SlimsegError
from slimseg.models.base import ZooModel
from slimseg.ops.nms import non_max_suppression, yolov3_to_rows

MIN_OPSET = 17
FP32_BOX_TOL_PX = 1e-3
FP32_SCORE_TOL = 1e-4
FP32_MASK_TOL = 1e-3  # raw coefficients and prototypes
FP16_MATCH_IOU = 0.9
FP16_SCORE_TOL = 0.02
FP32_LOGIT_TOL = 1e-3  # semantic models: per-pixel class logits
FP16_CLASS_AGREEMENT = 0.99  # semantic FP16: fraction of pixels with the FP32 argmax class


class ExportParityError(SlimsegError):
    """The exported graph does not compute what the fused torch model computes."""


@dataclass
class ExportReport:
    """What ``export_onnx`` wrote and measured."""

    path: Path
    sidecar: Path
    precision: str
    opset: int
    nodes: int
    ops: list[str]
    parity: dict[str, float] = field(default_factory=dict)


def output_names(model: ZooModel) -> list[str]:
    if model.spec.task == "semantic":
        return ["logits"]
    return ["output0", "output1"] if model.spec.task == "segment" else ["output0"]


def _parity_inputs(imgsz: tuple[int, int], seed: int = 0) -> list[np.ndarray]:
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


def _as_tuple(out: object) -> list[np.ndarray]:
    items = out if isinstance(out, tuple) else (out,)
    return [t.detach().float().numpy() for t in items]


def _iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.clip(rb - lt, 0, None).prod(-1)
    area_a = (a[:, 2:] - a[:, :2]).prod(-1)
    area_b = (b[:, 2:] - b[:, :2]).prod(-1)
    return inter / (area_a[:, None] + area_b[None] - inter + 1e-9)


def _rows(model: ZooModel, pred: np.ndarray) -> torch.Tensor:
    t = torch.from_numpy(pred).float()
    return yolov3_to_rows(t) if model.spec.family == "darknet-yolov3" else t


def check_fp32_parity(model: ZooModel, ref: list[np.ndarray], got: list[np.ndarray]) -> dict:
    """Max abs differences (boxes px, scores, mask terms); raises ExportParityError."""
    nc = model.num_classes
    ref_rows, got_rows = _rows(model, ref[0]).numpy(), _rows(model, got[0]).numpy()
    diffs = {
        "box_px": float(np.abs(ref_rows[:, :4] - got_rows[:, :4]).max()),
        "score": float(np.abs(ref_rows[:, 4 : 4 + nc] - got_rows[:, 4 : 4 + nc]).max()),
    }
    if ref_rows.shape[1] > 4 + nc or len(ref) > 1:
        parts = [np.abs(ref_rows[:, 4 + nc :] - got_rows[:, 4 + nc :]).max(initial=0.0)]
        parts += [np.abs(r - g).max() for r, g in zip(ref[1:], got[1:], strict=True)]
        diffs["mask_terms"] = float(max(parts))
    limits = {"box_px": FP32_BOX_TOL_PX, "score": FP32_SCORE_TOL, "mask_terms": FP32_MASK_TOL}
    bad = {k: v for k, v in diffs.items() if v > limits[k]}
    if bad:
        raise ExportParityError(
            f"FP32 ONNX differs from the fused torch model: {bad} (limits {limits})"
        )
    return diffs


def check_semantic_parity(
    model: nn.Module, ref: list[np.ndarray], got: list[np.ndarray], half: bool = False
) -> dict:
    """Semantic models: max abs logit difference and the fraction of pixels whose argmax class
    agrees. FP32: logits within ``FP32_LOGIT_TOL`` (so the class maps agree except at exact
    ties); FP16: at least ``FP16_CLASS_AGREEMENT`` of the pixels keep their class."""
    r, g = ref[0], got[0]
    if r.shape != g.shape:
        raise ExportParityError(f"ONNX logits {g.shape} differ from torch's {r.shape}")
    result = {
        "logit": float(np.abs(r - g).max()),
        "class_agreement": float((r.argmax(1) == g.argmax(1)).mean()),
    }
    if half and result["class_agreement"] < FP16_CLASS_AGREEMENT:
        raise ExportParityError(
            f"FP16 ONNX changed the class of {1 - result['class_agreement']:.2%} of the pixels "
            f"(at most {1 - FP16_CLASS_AGREEMENT:.0%} allowed)"
        )
    if not half and result["logit"] > FP32_LOGIT_TOL:
        raise ExportParityError(
            f"FP32 ONNX logits differ from the fused torch model by {result['logit']:.3g} "
            f"(limit {FP32_LOGIT_TOL})"
        )
    return result


def detection_agreement(
    model: nn.Module, ref: list[np.ndarray], got: list[np.ndarray], top: int = 20
) -> dict:
    """How closely ``got`` (an FP16 or INT8 graph's outputs) keeps the detections of ``ref``
    (FP32) on one input ``[1, ...]``: on every candidate anchor of ``ref`` (best class score
    ≥ 0.05, or the ``top`` best), the box IoU, the best-score difference and whether the class
    is the same (or two classes are within ``FP16_SCORE_TOL``). Checked per anchor, before
    NMS, so near-tied overlapping boxes cannot swap survivors. Returns ``checked``,
    ``matched`` (IoU ≥ ``FP16_MATCH_IOU``, score within ``FP16_SCORE_TOL``, same class),
    ``min_iou``, ``max_score_diff`` and, when both keep NMS survivors at 0.05, the fraction
    of ``ref``'s survivors matched (``nms_matched``)."""
    nc = model.num_classes
    r = _rows(model, ref[0])[0].numpy().T  # [A, 4 + nc (+ ...)]
    g = _rows(model, got[0])[0].numpy().T
    r_scores, g_scores = r[:, 4 : 4 + nc], g[:, 4 : 4 + nc]
    best = r_scores.max(1)
    candidates = np.flatnonzero(best >= 0.05)
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
    d_ref = non_max_suppression(_rows(model, ref[0]), nc, conf=0.05, max_det=300)[0]
    d_got = non_max_suppression(_rows(model, got[0]), nc, conf=0.05, max_det=300)[0]
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


def _quiet_exporter_warnings() -> None:
    """Inside a ``catch_warnings`` block: silence what the TorchScript exporter always says and
    what the parity check below covers, nothing else. Its deprecation notices (this exporter
    is deliberate: a plain static graph), and the tracer's "tensor to a Python boolean" notes
    from shape checks in forward (the traced branch is the one taken; parity then runs the
    graph, and with ``--dynamic`` also at batch 2 and another size)."""
    warnings.filterwarnings(
        "ignore",
        message=r"You are using the legacy TorchScript-based ONNX export",
        category=DeprecationWarning,
    )
    warnings.filterwarnings(
        "ignore",
        message=r"The feature will be removed",
        category=DeprecationWarning,
        module=r"torch\.onnx",
    )
    warnings.filterwarnings(
        "ignore",
        message=r"Converting a tensor to a Python boolean",
        category=torch.jit.TracerWarning,
    )


def _to_fp16(model_proto: onnx.ModelProto) -> onnx.ModelProto:
    """FP16 weights, compute and IO; the converter appends Cast nodes, so re-sort the graph."""
    from onnxruntime.transformers.float16 import convert_float_to_float16

    converted = convert_float_to_float16(model_proto, keep_io_types=False)
    _toposort(converted.graph)
    return converted


def _toposort(graph: onnx.GraphProto) -> None:
    """Order ``graph.node`` so every node follows the producers of its inputs (Kahn)."""
    available = {i.name for i in graph.input} | {t.name for t in graph.initializer} | {""}
    pending = list(graph.node)
    ordered: list[onnx.NodeProto] = []
    while pending:
        ready = [n for n in pending if all(i in available for i in n.input)]
        if not ready:
            raise SlimsegError("ONNX graph has a cycle or a dangling input after conversion")
        for n in ready:
            ordered.append(n)
            available.update(n.output)
        ids = {id(n) for n in ready}
        pending = [n for n in pending if id(n) not in ids]
    copies = [onnx.NodeProto.FromString(n.SerializeToString()) for n in ordered]
    del graph.node[:]
    graph.node.extend(copies)


def export_onnx(
    model: ZooModel,
    out: str | Path,
    imgsz: tuple[int, int] = (640, 640),
    names: list[str] | None = None,
    mobility: list[float] | None = None,
    half: bool = False,
    dynamic: bool = False,
    opset: int = 18,
    simplify: bool = True,
) -> ExportReport:
    """Export ``model`` (fused here) to ``out``; the file appears only after parity passes."""
    if opset < MIN_OPSET:
        raise SlimsegError(f"--opset {opset}: need >= {MIN_OPSET} (TensorRT 8.6+/10 parse it)")
    h, w = imgsz
    if h % 32 or w % 32:
        raise SlimsegError(f"--imgsz {h}x{w}: both sides must be multiples of 32")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fused = model.fuse()
    fused = fused.float().eval().requires_grad_(False)
    outputs = output_names(fused)
    axes = None
    if dynamic and outputs == ["logits"]:
        axes = {
            "images": {0: "batch", 2: "height", 3: "width"},
            "logits": {0: "batch", 2: "height", 3: "width"},
        }
    elif dynamic:
        axes = {
            "images": {0: "batch", 2: "height", 3: "width"},
            "output0": {0: "batch", 2: "anchors"},
        }
        if len(outputs) > 1:
            axes["output1"] = {0: "batch", 2: "mask_height", 3: "mask_width"}
    precision = "fp16" if half else "fp32"
    meta = build_metadata(fused, names or [], mobility or [], imgsz, precision, dynamic)
    with tempfile.TemporaryDirectory(dir=out.parent, prefix=f".{out.stem}.") as tmp_dir:
        raw = Path(tmp_dir) / "raw.onnx"
        with warnings.catch_warnings(), torch.no_grad():
            _quiet_exporter_warnings()
            torch.onnx.export(
                fused,
                torch.zeros(1, 3, h, w),
                str(raw),
                opset_version=opset,
                input_names=["images"],
                output_names=outputs,
                dynamic_axes=axes,
                do_constant_folding=True,
                dynamo=False,
            )
        proto = onnx.load(str(raw))
        onnx.checker.check_model(proto)
        proto = onnx.shape_inference.infer_shapes(proto)
        if simplify:
            import onnxslim

            proto = onnxslim.slim(proto)
        if half:
            proto = _to_fp16(proto)
        del proto.metadata_props[:]
        for key, value in to_metadata_props(meta).items():
            entry = proto.metadata_props.add()
            entry.key, entry.value = key, value
        onnx.checker.check_model(proto)
        candidate = Path(tmp_dir) / out.name
        onnx.save(proto, str(candidate))
        parity = verify_parity(fused, candidate, imgsz, half)
        sidecar_tmp = Path(tmp_dir) / "sidecar.json"
        sidecar_tmp.write_text(json.dumps(meta, indent=1))
        os.replace(candidate, out)
        sidecar = out.with_suffix(".json")
        os.replace(sidecar_tmp, sidecar)
    ops = sorted({n.op_type for n in proto.graph.node})
    return ExportReport(out, sidecar, precision, opset, len(proto.graph.node), ops, parity)


def second_size(imgsz: tuple[int, int]) -> tuple[int, int]:
    """The other input size a ``--dynamic`` export is checked at: 32 px taller, 64 px wider
    (non-square, so a swapped H/W axis shows)."""
    return imgsz[0] + 32, imgsz[1] + 64


def _checked_inputs(imgsz: tuple[int, int], dynamic: bool) -> list[tuple[str, np.ndarray]]:
    """``(tag, input [B, 3, H, W])``: the two parity inputs; for dynamic exports also both in
    one batch of 2 and a scene at :func:`second_size`."""
    first = _parity_inputs(imgsz)
    inputs = [(f"input{k}", x) for k, x in enumerate(first)]
    if dynamic:
        h, w = second_size(imgsz)
        inputs.append(("batch2", np.concatenate(first)))
        inputs.append((f"size{h}x{w}", _parity_inputs((h, w), seed=1)[1]))
    return inputs


def verify_parity(
    fused: nn.Module, path: Path, imgsz: tuple[int, int], half: bool
) -> dict[str, float]:
    """Run onnxruntime and the fused torch model on the parity inputs (a graph with a dynamic
    input shape also at batch 2 and a second H×W); every output is compared; raise on
    disagreement."""
    session = cpu_session(path)
    dynamic = not all(isinstance(d, int) for d in session.get_inputs()[0].shape)
    results: dict[str, float] = {}
    for tag, x in _checked_inputs(imgsz, dynamic):
        with torch.no_grad():
            ref = _as_tuple(fused(torch.from_numpy(x)))
        feed = x.astype(np.float16) if half else x
        got = [o.astype(np.float32) for o in session.run(None, {"images": feed})]
        shapes = [r.shape for r in ref], [g.shape for g in got]
        if shapes[0] != shapes[1]:
            raise ExportParityError(
                f"ONNX output shapes {shapes[1]} differ from torch's {shapes[0]} ({tag})"
            )
        if fused.spec.task == "semantic":
            checked = check_semantic_parity(fused, ref, got, half)
        elif half:  # per image: the detection check reads one image's rows
            per = [
                check_fp16_parity(fused, [r[b : b + 1] for r in ref], [g[b : b + 1] for g in got])
                for b in range(len(x))
            ]
            checked = {k: sum(p[k] for p in per) for k in ("checked", "matched")}
            checked["min_iou"] = min(p["min_iou"] for p in per)
            checked["max_score_diff"] = max(p["max_score_diff"] for p in per)
        else:
            checked = check_fp32_parity(fused, ref, got)
        for key, value in checked.items():
            results[f"{tag}/{key}"] = value
    return results
