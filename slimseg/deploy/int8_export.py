"""INT8 export with an accuracy gate: nothing reaches its final path that lost too much mAP.

Pipeline: the parity-checked FP32 export (:func:`~slimseg.deploy.onnx_export.export_onnx`,
into the staging folder) → calibration on real frames → the target's Q/DQ graph
(:func:`~slimseg.deploy.int8_quantize.quantize_onnx`; ``tensorrt``: symmetric INT8, convs only;
``onnxruntime``: U8S8, the whole network body) → COCO box and mask mAP50-95 of the FP32
and the INT8 graph on the same val split with the same evaluator
(:func:`~slimseg.eval.validation.validate_dataset` over
:class:`~slimseg.deploy.onnx_model.OnnxModel`) → refuse when either drops more than
``max_drop`` points → agreement with FP32 on the calibration frames → metadata → rename into
place, plus the ``NAME.json`` sidecar (:mod:`slimseg.deploy.onnx_io`, shared with the FP32
exporter).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import onnx
from torch import nn
from tqdm import tqdm

from slimseg.data.coco import CocoDataset
from slimseg.data.config import DataConfig, load_data_config
from slimseg.data.dataset import ZooDataset
from slimseg.deploy.calibration import CalibrationSet, load_calibration_set
from slimseg.deploy.int8_placement import DEFAULT_INT8_TARGET, check_family, check_target
from slimseg.deploy.int8_quantize import QUANTIZATION, check_onnxruntime, quantize_onnx
from slimseg.deploy.metadata import build_metadata
from slimseg.deploy.onnx_export import export_onnx
from slimseg.deploy.onnx_io import publish, stage, staging_dir
from slimseg.deploy.onnx_model import OnnxModel
from slimseg.deploy.parity import detection_agreement
from slimseg.errors import SlimsegError
from slimseg.eval.validation import validate_dataset

DEFAULT_MAX_DROP = 1.0  # mAP50-95 points, box and mask alike


class Int8AccuracyError(SlimsegError):
    """The INT8 graph lost more mAP than allowed; nothing was written."""


@dataclass
class Int8Report:
    """What :func:`export_int8` wrote and measured (mAP50-95 in points, 0–100; ``results``:
    the evaluator's full output per graph, ``fp32`` and ``int8``, per-class rows included)."""

    path: Path
    sidecar: Path
    nodes: int
    quantized_convs: int
    placement: dict[str, int]
    calib_images: int
    calib_skipped: int
    map_fp32: dict[str, float]
    map_int8: dict[str, float]
    agreement: dict[str, float] = field(default_factory=dict)
    target: str = DEFAULT_INT8_TARGET
    results: dict[str, dict] = field(default_factory=dict)


def _points(result: dict) -> dict[str, float]:
    out = {"box": 100 * float(result["box"]["map50_95"])}
    if result.get("mask"):
        out["mask"] = 100 * float(result["mask"]["map50_95"])
    return out


def score_onnx(
    path: Path, data: DataConfig, imgsz: int, batch: int = 8, progress: bool = True
) -> dict:
    """COCO metrics of an exported graph on ``data``'s val split (``slimseg val``'s evaluator)."""
    model = OnnxModel(path)
    base = CocoDataset.from_config(data, "val")
    result, _ = validate_dataset(model, ZooDataset(base, imgsz), batch, 0, progress=progress)
    return result


def agreement_on_frames(
    fp32: OnnxModel, int8: OnnxModel, calib: CalibrationSet, imgsz: tuple[int, int], progress: bool
) -> dict[str, float]:
    """:func:`~slimseg.deploy.parity.detection_agreement` of INT8 vs FP32 summed over the
    calibration frames: ``frames``, ``checked``, ``matched``, ``matched_fraction``, the lowest
    ``min_iou``, the largest ``max_score_diff`` and the mean ``nms_matched``."""
    totals = {"frames": 0, "checked": 0, "matched": 0, "min_iou": 1.0, "max_score_diff": 0.0}
    nms: list[float] = []
    bar = tqdm(calib.inputs(imgsz), total=len(calib.paths), desc="agreement", disable=not progress)
    for x in bar:
        ref = [t for t in fp32.runner(x) if t is not None]
        got = [t for t in int8.runner(x) if t is not None]
        a = detection_agreement(fp32, ref, got)
        totals["frames"] += 1
        totals["checked"] += a["checked"]
        totals["matched"] += a["matched"]
        totals["min_iou"] = min(totals["min_iou"], a["min_iou"])
        totals["max_score_diff"] = max(totals["max_score_diff"], a["max_score_diff"])
        if "nms_matched" in a:
            nms.append(a["nms_matched"])
    totals["matched_fraction"] = totals["matched"] / max(totals["checked"], 1)
    if nms:
        totals["nms_matched"] = sum(nms) / len(nms)
    return totals


def _gate(
    fp32: dict[str, float], int8: dict[str, float], max_drop: float, target: str = "tensorrt"
) -> None:
    drops = {k: fp32[k] - int8.get(k, 0.0) for k in fp32}
    if any(d > max_drop for d in drops.values()):
        numbers = ", ".join(f"{k} {fp32[k]:.2f} -> {int8[k]:.2f}" for k in fp32)
        raise Int8AccuracyError(
            f"INT8 refused ({target} target): mAP50-95 FP32 -> INT8 {numbers} (drop "
            + ", ".join(f"{k} {d:.2f}" for k, d in drops.items())
            + f" points > --int8-max-drop {max_drop}); nothing written. Try --calib-method "
            "percentile or entropy, more --calib-images, or deploy FP16/FP32"
        )


def export_int8(
    model: nn.Module,
    out: str | Path,
    calib_source: str | Path,
    imgsz: tuple[int, int] = (640, 640),
    names: list[str] | None = None,
    mobility: list[float] | None = None,
    calib_images: int | None = None,
    method: str = "minmax",
    max_drop: float = DEFAULT_MAX_DROP,
    val_data: str | Path | None = None,
    opset: int = 18,
    progress: bool = True,
    target: str = DEFAULT_INT8_TARGET,
) -> Int8Report:
    """Export ``model`` as a calibrated INT8 Q/DQ ONNX file at ``out``, gated on mAP.

    ``calib_source``: a data YAML (its val split calibrates and gates) or a folder of frames
    (then ``val_data``, a data YAML, gates). ``max_drop``: the most mAP50-95 points box or
    mask may lose. ``target``: ``tensorrt`` (TensorRT's explicit quantization) or
    ``onnxruntime`` (onnxruntime's CPU kernels). Raises :class:`Int8AccuracyError` (no file)
    when the gate fails.
    """
    check_onnxruntime()
    check_target(target)
    check_family(model.spec.family, model.spec.name)
    if imgsz[0] != imgsz[1]:
        raise SlimsegError(
            f"--int8 --imgsz {imgsz[0]} {imgsz[1]}: the accuracy gate scores square inputs; "
            "pass one size"
        )
    if max_drop < 0:
        raise SlimsegError(f"--int8-max-drop {max_drop}: must be >= 0 (mAP points)")
    calib = load_calibration_set(calib_source, calib_images)
    data = load_data_config(val_data) if val_data is not None else calib.data
    if data is None:
        raise SlimsegError(
            f"--calib {calib_source} is a folder (no labels): pass --int8-val DATA.yaml so the "
            "INT8 graph can be scored against FP32 before it is written"
        )
    if len(data.names) != model.num_classes:
        raise SlimsegError(
            f"{data.source}: {len(data.names)} classes but the model predicts "
            f"{model.num_classes}; gate on the dataset it was trained for"
        )
    out = Path(out)
    with staging_dir(out) as tmp_dir:
        tmp = Path(tmp_dir)
        fp32_path = export_onnx(model, tmp / "fp32.onnx", imgsz, names, mobility, opset=opset).path
        q_path = tmp / "int8.onnx"
        family = model.spec.family
        plan = quantize_onnx(
            fp32_path, q_path, calib, imgsz, family, method, progress, target=target
        )
        results = {
            "fp32": score_onnx(fp32_path, data, imgsz[0], progress=progress),
            "int8": score_onnx(q_path, data, imgsz[0], progress=progress),
        }
        map_fp32, map_int8 = _points(results["fp32"]), _points(results["int8"])
        _gate(map_fp32, map_int8, max_drop, target)
        agreement = agreement_on_frames(
            OnnxModel(fp32_path), OnnxModel(q_path), calib, imgsz, progress
        )
        meta = build_metadata(model, names or [], mobility or [], imgsz, "int8")
        meta["int8"] = {
            "target": target,
            "calibration": {
                "method": method,
                "images": len(calib.paths),
                "source": calib.source.name,
                "data_hash": calib.digest,
            },
            "quantization": dict(QUANTIZATION[target]),
            "placement": plan.summary(),
            "map50_95": {"fp32": map_fp32, "int8": map_int8},
            "gated_on": data.source.name,
            "max_drop": max_drop,
            "agreement": agreement,
        }
        if plan.ops:
            meta["int8"]["quantized_ops"] = dict(plan.ops)
        proto = onnx.load(str(q_path))
        sidecar = publish(stage(proto, meta, tmp, out.name), meta, out)
    return Int8Report(
        out,
        sidecar,
        len(proto.graph.node),
        plan.ops.get("Conv", len(plan.quantize)),
        plan.summary(),
        len(calib.paths),
        calib.skipped,
        map_fp32,
        map_int8,
        agreement,
        target,
        results,
    )
