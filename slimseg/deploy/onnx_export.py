"""ONNX export with a verified parity check: nothing reaches its final path unverified.

Pipeline: eval model → fuse (Conv+BN, RepConv) → ``torch.onnx.export`` (opset ≥ 17, TorchScript
exporter: a plain static graph) → onnx checker + shape inference → onnxslim → FP16 conversion
(``--half``: FP16 weights, compute, input and outputs) → metadata → parity against the fused
torch model on two inputs with onnxruntime (:mod:`slimseg.deploy.parity`) → rename into place,
plus a ``NAME.json`` sidecar (:mod:`slimseg.deploy.onnx_io`). ``end2end``: that verified raw
graph plus the post-processing sub-graph (:mod:`slimseg.deploy.end2end_graph`), gated on the
instances of ``slimseg predict``'s raw path (:mod:`slimseg.deploy.end2end_parity`).
"""

from __future__ import annotations

import copy
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import onnx
import torch
from torch import nn

from slimseg.deploy.end2end_graph import End2EndSettings, append_end2end
from slimseg.deploy.end2end_parity import (
    GATE_CONF,
    MIN_INSTANCES,
    gate_frames,
    low_gate_conf,
    verify_end2end,
)
from slimseg.deploy.metadata import build_metadata, with_end2end
from slimseg.deploy.onnx_io import publish, stage, staging_dir
from slimseg.deploy.parity import verify_parity
from slimseg.deploy.predictor import Predictor
from slimseg.errors import SlimsegError
from slimseg.models.base import ZooModel

MIN_OPSET = 17


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
    """The graph's output names: ``logits`` (semantic), ``output0`` (+ ``output1``, the
    prototypes of segmenters); ``export/CONTRACT.md`` gives their shapes."""
    if model.spec.task == "semantic":
        return ["logits"]
    return ["output0", "output1"] if model.spec.task == "segment" else ["output0"]


def _dynamic_axes(outputs: list[str]) -> dict[str, dict[int, str]]:
    """``--dynamic``: batch, height and width of ``images [B, 3, H, W]`` and of every output."""
    axes = {"images": {0: "batch", 2: "height", 3: "width"}}
    if outputs == ["logits"]:
        axes["logits"] = {0: "batch", 2: "height", 3: "width"}
        return axes
    axes["output0"] = {0: "batch", 2: "anchors"}
    if len(outputs) > 1:
        axes["output1"] = {0: "batch", 2: "mask_height", 3: "mask_width"}
    return axes


def _quiet_exporter_warnings() -> None:
    """Inside a ``catch_warnings`` block: silence what the TorchScript exporter always says and
    what the parity check covers, nothing else. Its deprecation notices (this exporter is
    deliberate: a plain static graph), and the tracer's "tensor to a Python boolean" notes
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


def _trace(
    fused: nn.Module, imgsz: tuple[int, int], raw: Path, opset: int, dynamic: bool
) -> onnx.ModelProto:
    """``torch.onnx.export`` of ``fused`` on ``images [1, 3, H, W]`` into ``raw``; returns the
    checked graph with inferred shapes."""
    outputs = output_names(fused)
    with warnings.catch_warnings(), torch.no_grad():
        _quiet_exporter_warnings()
        torch.onnx.export(
            fused,
            torch.zeros(1, 3, *imgsz),
            str(raw),
            opset_version=opset,
            input_names=["images"],
            output_names=outputs,
            dynamic_axes=_dynamic_axes(outputs) if dynamic else None,
            do_constant_folding=True,
            dynamo=False,
        )
    proto = onnx.load(str(raw))
    onnx.checker.check_model(proto)
    return onnx.shape_inference.infer_shapes(proto)


def to_fp16(model_proto: onnx.ModelProto) -> onnx.ModelProto:
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


def _low_conf_twin(
    raw_path: Path, proto: onnx.ModelProto, meta: dict, settings: End2EndSettings,
    shape: tuple, imgsz: tuple[int, int],
) -> tuple[Path, float] | None:  # fmt: skip
    """When the raw graph gives fewer than ``MIN_INSTANCES`` detections at the gate's conf:
    a twin of the end-to-end graph baked at :func:`low_gate_conf`, staged beside the raw one,
    and that conf (None otherwise)."""
    nm, batch, anchors = shape
    conf = max(GATE_CONF, settings.conf)
    ref = Predictor.from_path(raw_path, threads=1)
    found = sum(len(ref.predict(f, conf, settings.iou, settings.max_det).scores)
                for f in gate_frames(imgsz))  # fmt: skip
    if found >= MIN_INSTANCES:
        return None
    low = min(low_gate_conf(raw_path, imgsz, settings.iou, settings.max_det), settings.conf)
    twin = replace(settings, conf=low)
    nc = len(meta["names"])
    graph = append_end2end(copy.deepcopy(proto), nc, nm, twin, batch, anchors)
    return stage(graph, with_end2end(meta, twin.as_dict()), raw_path.parent,
                 f"low-{raw_path.name}"), low  # fmt: skip


def check_end2end_model(model: ZooModel) -> None:
    """``SlimsegError`` unless ``model`` can take the end-to-end sub-graph: a YOLOv8 detector
    or segmenter (Darknet YOLOv3 rows and MSNET class maps have no such graph yet)."""
    spec = model.spec
    if spec.family != "yolov8" or spec.task not in ("detect", "segment"):
        raise SlimsegError(
            f"--end2end: {spec.name} ({spec.family}, {spec.task}) has no end-to-end graph; "
            "it is made for yolov8 detectors and segmenters (export without --end2end)"
        )


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
    end2end: End2EndSettings | None = None,
) -> ExportReport:
    """Export ``model`` (fused here) to ``out`` for input ``images [B, 3, H, W]`` with
    ``(H, W) = imgsz``; the file appears only after parity passes
    (:func:`~slimseg.deploy.parity.verify_parity`, else :class:`ExportParityError`).
    ``end2end``: write the end-to-end graph instead (NMS and masks inside), which must also
    give the raw graph's instances (:func:`~slimseg.deploy.end2end_parity.verify_end2end`)."""
    if opset < MIN_OPSET:
        raise SlimsegError(f"--opset {opset}: need >= {MIN_OPSET} (TensorRT 8.6+/10 parse it)")
    h, w = imgsz
    if h % 32 or w % 32:
        raise SlimsegError(f"--imgsz {h}x{w}: both sides must be multiples of 32")
    if end2end is not None:
        check_end2end_model(model)
    out = Path(out)
    fused = model.fuse().float().eval().requires_grad_(False)
    precision = "fp16" if half else "fp32"
    meta = build_metadata(fused, names or [], mobility or [], imgsz, precision, dynamic)
    with staging_dir(out) as tmp_dir:
        proto = _trace(fused, imgsz, Path(tmp_dir) / "raw.onnx", opset, dynamic)
        if simplify:
            import onnxslim

            proto = onnxslim.slim(proto)
        if half:
            proto = to_fp16(proto)
        raw_name = f"raw-{out.name}" if end2end is not None else out.name
        candidate = stage(proto, meta, tmp_dir, raw_name)
        parity = verify_parity(fused, candidate, imgsz, half)
        if end2end is not None:
            raw_path = candidate
            nm = int(meta.get("num_masks", 0))
            batch = "batch" if dynamic else 1
            end2end = replace(end2end, proto_stride=int(meta.get("proto_stride", 4)))
            anchors = None if dynamic else sum((h // s) * (w // s) for s in meta["strides"])
            low = (
                None
                if half
                else _low_conf_twin(  # FP16 cannot resolve scores near 1e-4
                    raw_path, proto, meta, end2end, (nm, batch, anchors), imgsz
                )
            )
            proto = append_end2end(proto, model.num_classes, nm, end2end, batch, anchors)
            meta = with_end2end(meta, end2end.as_dict())
            candidate = stage(proto, meta, tmp_dir, out.name)
            parity.update(verify_end2end(raw_path, candidate, imgsz, dynamic))
            if low is not None:  # few detections at the gate's conf: compare the twin too
                twin, conf = low
                parity.update(verify_end2end(raw_path, twin, imgsz, dynamic, conf, "end2end_low"))
        sidecar = publish(candidate, meta, out)
    ops = sorted({n.op_type for n in proto.graph.node})
    return ExportReport(out, sidecar, precision, opset, len(proto.graph.node), ops, parity)
