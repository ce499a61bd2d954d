"""Latency of one model in every form, measured side by side in one process.

torch unfused, torch fused, onnxruntime FP32 and FP16 (exported with the parity-checked
exporter into a temporary folder) and, given calibration frames, the INT8 Q/DQ file of each
target (``int8_trt``: the TensorRT file run by onnxruntime; ``int8_ort``: the onnxruntime
file), plus NMS + mask post-processing (semantic models: the class map on a 640 × 480 frame,
i.e. crop, bilinear resize of the logits and argmax).
Median of ``runs`` timed calls after ``warmup`` untimed ones, batch 1, ``threads`` intra-op
threads everywhere; onnxruntime sessions never spin idle threads (they would steal the cores
from the others).
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import nn

from slimseg.deploy.calibration import CalibrationSet
from slimseg.deploy.int8_placement import INT8_TARGETS, check_target
from slimseg.deploy.int8_quantize import quantize_onnx
from slimseg.deploy.onnx_export import export_onnx
from slimseg.deploy.ort_session import cpu_session
from slimseg.deploy.ov_session import OpenVinoSession
from slimseg.detections import Detections
from slimseg.eval.postprocess import to_frame_detections
from slimseg.models.registry import detection_rows
from slimseg.ops.letterbox import letterbox_params
from slimseg.ops.nms import PREDICT_CONF, non_max_suppression
from slimseg.ops.semantic import logits_to_frame
from slimseg.utils.cpu_features import detect_cpu_features
from slimseg.utils.threads import torch_threads


def median_ms(fn: Callable[[], object], runs: int, warmup: int) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


FORMS = ("torch", "torch_fused", "ort_fp32", "ort_fp16")
# The form name of each INT8 target's file in a bench result.
INT8_FORMS = {"tensorrt": "int8_trt", "onnxruntime": "int8_ort"}


def alternating_median_ms(
    fns: dict[str, Callable[[], object]], runs: int, warmup: int
) -> dict[str, float]:
    """Median milliseconds of each function, timed round-robin (one call of each per round)."""
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    times: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(runs):
        for key, fn in fns.items():
            start = time.perf_counter()
            fn()
            times[key].append(time.perf_counter() - start)
    return {k: 1000 * statistics.median(v) for k, v in times.items()}


def _session_call(path: Path, threads: int, x: torch.Tensor, half: bool) -> Callable[[], object]:
    session = cpu_session(path, threads)
    feed = {"images": x.numpy().astype(np.float16 if half else np.float32)}
    return lambda: session.run(None, feed)


def _openvino_call(path: Path, threads: int, x: torch.Tensor, half: bool) -> Callable[[], object]:
    session = OpenVinoSession(path, threads)
    feed = {session.get_inputs()[0].name: x.numpy().astype(np.float16 if half else np.float32)}
    names = [o.name for o in session.get_outputs()]
    return lambda: session.run(names, feed)


def bench_model(
    model: nn.Module,
    imgsz: int = 640,
    threads: int = 2,
    runs: int = 10,
    warmup: int = 3,
    forms: tuple[str, ...] = FORMS,
    calib: CalibrationSet | None = None,
    calib_method: str = "minmax",
    int8_targets: tuple[str, ...] = INT8_TARGETS,
    openvino: bool = False,
) -> dict[str, float]:
    """Milliseconds per form (plus ``postprocess``) for one model; torch runs with
    ``threads`` threads and the process-wide count is restored afterwards.

    ``openvino``: every ONNX form also in OpenVINO at f32 (``ov_fp32``, ``ov_fp16``,
    ``ov_int8_trt``, ...: the same file, timed in the same rounds; its INT8 kernels as they
    are, without the run-time check of :mod:`slimseg.deploy.ov_session`: speed only).

    ``calib`` (calibration frames) adds one form per ``int8_targets`` entry
    (:data:`INT8_FORMS`): the FP32 export quantized as ``slimseg export --int8
    --int8-target T`` quantizes it (same placement and calibration; no accuracy gate: this
    measures speed). The onnxruntime forms are timed in alternation, one call each per
    round, so a load change on the machine hits all of them alike.
    """
    for target in int8_targets:
        check_target(target)
    with torch_threads(threads):
        return _bench(
            model, imgsz, threads, runs, warmup, forms, calib, calib_method, int8_targets, openvino
        )


def _bench(
    model: nn.Module,
    imgsz: int,
    threads: int,
    runs: int,
    warmup: int,
    forms: tuple[str, ...],
    calib: CalibrationSet | None,
    calib_method: str,
    int8_targets: tuple[str, ...],
    openvino: bool = False,
) -> dict[str, float]:
    model = model.eval()
    fused = model.fuse()
    x = torch.rand(1, 3, imgsz, imgsz)
    result: dict[str, float] = {}
    with torch.no_grad():
        if "torch" in forms:
            result["torch"] = median_ms(lambda: model(x), runs, warmup)
        if "torch_fused" in forms:
            result["torch_fused"] = median_ms(lambda: fused(x), runs, warmup)
        out = fused(x)
    with tempfile.TemporaryDirectory() as tmp:
        runs_by_form: dict[str, Callable[[], object]] = {}
        fp32_path = None
        for form, half in (("ort_fp32", False), ("ort_fp16", True)):
            if form not in forms and not (form == "ort_fp32" and calib is not None):
                continue
            path = export_onnx(model, Path(tmp) / f"{form}.onnx", (imgsz, imgsz), half=half).path
            fp32_path = path if not half else fp32_path
            if form in forms:
                runs_by_form[form] = _session_call(path, threads, x, half)
                if openvino:
                    runs_by_form[f"ov_{form[4:]}"] = _openvino_call(path, threads, x, half)
        for target in int8_targets if calib is not None else ():
            form = INT8_FORMS[target]
            q = Path(tmp) / f"{form}.onnx"
            family = model.spec.family
            hw = (imgsz, imgsz)
            quantize_onnx(fp32_path, q, calib, hw, family, calib_method, False, target=target)
            runs_by_form[form] = _session_call(q, threads, x, False)
            if openvino:
                runs_by_form[f"ov_{form}"] = _openvino_call(q, threads, x, False)
        result.update(alternating_median_ms(runs_by_form, runs, warmup))
    result["postprocess"] = median_ms(lambda: _postprocess(model, out, imgsz), runs, warmup)
    return result


def _postprocess(model: nn.Module, out: object, imgsz: int) -> list[object]:
    meta = {"letterbox": letterbox_params(480, 640, imgsz), "orig_shape": (480, 640)}
    if model.spec.task == "semantic":
        return [logits_to_frame(o, meta["letterbox"], meta["orig_shape"]) for o in out]
    pred, proto = out if isinstance(out, tuple) else (out, None)
    pred = detection_rows(model.spec.family, pred)
    dets: list[Detections] = non_max_suppression(pred, model.num_classes, conf=PREDICT_CONF)
    return [to_frame_detections(d, None if proto is None else proto[0], meta) for d in dets]


def machine_info() -> dict[str, object]:
    """What decides the INT8 figures besides the model: the CPU's INT8 instruction sets
    (:func:`~slimseg.utils.cpu_features.detect_cpu_features`), onnxruntime's version, the
    core count and the load average (1, 5, 15 min) at the time of the call."""
    import onnxruntime

    cpu = detect_cpu_features()
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    return {
        **cpu.as_dict(),
        "describe": cpu.describe(),
        "onnxruntime": onnxruntime.__version__,
        "cores": os.cpu_count(),
        "load_average": [round(v, 2) for v in load],
    }
