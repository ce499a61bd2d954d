"""FP32 ONNX → INT8 Q/DQ ONNX with ``onnxruntime.quantization``, for one of two targets.

``quant_pre_process`` (shape inference, graph clean-up), then ``quantize_static`` in QDQ format
with per-channel symmetric INT8 weights and per-tensor activations, on the nodes the target's
placement (:mod:`slimseg.deploy.int8_placement`) selects:

* ``tensorrt``: symmetric INT8 activations (every zero point 0: TensorRT's parser accepts
  nothing else), biases left in float (TensorRT rejects onnxruntime's int32 bias
  ``DequantizeLinear``), Q/DQ on the chosen Conv nodes only. Builds a TensorRT engine with
  explicit quantization (``export/build_engine.sh``); onnxruntime runs it too, slowly on x86.
* ``onnxruntime``: asymmetric UINT8 activations (U8S8, the form onnxruntime's fast x86 and
  ARM INT8 kernels take), int32 biases, every operator of the network body quantized. Not
  for TensorRT.
"""

from __future__ import annotations

import contextlib
import io
import logging
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import onnx
from tqdm import tqdm

from slimseg.deploy.calibration import CalibrationSet
from slimseg.deploy.int8_placement import (
    DEFAULT_INT8_TARGET,
    ORT_QUANTIZE_DEPTHWISE,
    QUANTIZE_DEPTHWISE,
    Placement,
    check_target,
    plan_placement,
    plan_placement_ort,
)
from slimseg.errors import SlimsegError

log = logging.getLogger(__name__)

# Symmetric per-channel Q/DQ with QuantizeBias=False needs this onnxruntime (or newer).
MIN_ONNXRUNTIME = (1, 17)
CALIB_METHODS = ("minmax", "percentile", "entropy")
# Entropy (KL) calibration: histogram bins, and the levels of the 8-bit tensor it searches a
# window for. quantize_static's own entropy calibrator uses 128 and 128, which leaves one
# window, the full range: the ranges of minmax (docs/int8.md).
ENTROPY_BINS = 2048
ENTROPY_QUANTIZED_BINS = 255
# Operators each target's file quantizes (None: every one onnxruntime can).
QUANTIZED_OPS: dict[str, list[str] | None] = {"tensorrt": ["Conv"], "onnxruntime": None}
MIN_INT8_OPSET = 13  # per-channel QuantizeLinear/DequantizeLinear (axis attribute)
# What each target's file holds (the ``int8.quantization`` metadata entry).
QUANTIZATION = {
    "tensorrt": {
        "format": "QDQ",
        "weights": "int8, symmetric, per output channel",
        "activations": "int8, symmetric, per tensor",
        "bias": "float (not quantized)",
    },
    "onnxruntime": {
        "format": "QDQ",
        "weights": "int8, symmetric, per output channel",
        "activations": "uint8, asymmetric, per tensor",
        "bias": "int32 (scale: input scale x weight scale)",
    },
}


def _version_tuple(text: str) -> tuple[int, ...]:
    parts = []
    for piece in text.split(".")[:3]:
        digits = "".join(ch for ch in piece if ch.isdigit())
        parts.append(int(digits) if digits else 0)
    return tuple(parts)


def check_onnxruntime(version: str | None = None) -> None:
    """:class:`SlimsegError` unless onnxruntime (``version``, default the installed one) can
    write symmetric per-channel Q/DQ graphs."""
    if version is None:
        import onnxruntime

        version = onnxruntime.__version__
    if _version_tuple(version) < MIN_ONNXRUNTIME:
        need = ".".join(map(str, MIN_ONNXRUNTIME))
        raise SlimsegError(
            f"--int8: onnxruntime {version} is too old for symmetric per-channel Q/DQ "
            f"(need >= {need}): pip install -U 'onnxruntime>={need}'"
        )


def _calibrate_method(name: str):
    from onnxruntime.quantization import CalibrationMethod

    methods = {
        "minmax": CalibrationMethod.MinMax,
        "percentile": CalibrationMethod.Percentile,
        "entropy": CalibrationMethod.Entropy,
    }
    if name not in methods:
        raise SlimsegError(f"--calib-method {name}: choose one of {', '.join(CALIB_METHODS)}")
    return methods[name]


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """onnxruntime's histogram calibrators ``print`` progress; route it to the debug log so a
    command's standard output holds only its own report."""
    buffer = io.StringIO()
    try:
        with contextlib.redirect_stdout(buffer):
            yield
    finally:
        for line in buffer.getvalue().splitlines():
            log.debug("onnxruntime.quantization: %s", line)


def _reader(calib: CalibrationSet, imgsz: tuple[int, int], progress: bool):
    from onnxruntime.quantization import CalibrationDataReader

    class _Frames(CalibrationDataReader):
        """Feeds ``{"images": float32 [1, 3, H, W]}`` per calibration frame."""

        def __init__(self) -> None:
            self._inputs = calib.inputs(imgsz)
            self._bar = tqdm(total=len(calib.paths), desc="calibrate", disable=not progress)

        def get_next(self) -> dict[str, np.ndarray] | None:
            x = next(self._inputs, None)
            if x is None:
                self._bar.close()
                return None
            self._bar.update()
            return {"images": x}

    return _Frames()


def quantize_onnx(
    fp32_path: Path,
    out_path: Path,
    calib: CalibrationSet,
    imgsz: tuple[int, int],
    family: str,
    method: str = "minmax",
    progress: bool = True,
    quantize_depthwise: bool | None = None,
    target: str = DEFAULT_INT8_TARGET,
) -> Placement:
    """Write ``target``'s INT8 Q/DQ graph of ``fp32_path`` to ``out_path``; returns the
    placement. ``quantize_depthwise``: override the target's depthwise rule (measurements).

    ``out_path``'s folder also receives the pre-processed intermediate (``*.pre.onnx``).
    """
    check_onnxruntime()
    check_target(target)
    from onnxruntime.quantization.shape_inference import quant_pre_process

    calibrate_method = _calibrate_method(method)
    opset = max(
        o.version for o in onnx.load(str(fp32_path)).opset_import if o.domain in ("", "ai.onnx")
    )
    if opset < MIN_INT8_OPSET:
        raise SlimsegError(f"--int8 needs opset >= {MIN_INT8_OPSET} (got {opset}): pass --opset 18")
    pre = out_path.with_suffix(".pre.onnx")
    quant_pre_process(str(fp32_path), str(pre), skip_symbolic_shape=False)
    reader = _reader(calib, imgsz, progress)
    graph = onnx.load(str(pre))
    if target == "onnxruntime":
        dw = ORT_QUANTIZE_DEPTHWISE if quantize_depthwise is None else quantize_depthwise
        plan = plan_placement_ort(graph, family, dw)
        log.info("INT8 placement (onnxruntime): %s; ops %s", plan.summary(), plan.ops)
    else:
        dw = QUANTIZE_DEPTHWISE if quantize_depthwise is None else quantize_depthwise
        plan = plan_placement(graph, family, dw)
        log.info("INT8 placement: %s", plan.summary())
    with _quiet_stdout():
        ops = QUANTIZED_OPS[target]
        cache = _entropy_cache(pre, reader, ops) if method == "entropy" else None
        _quantize(pre, out_path, None if cache else reader, plan, calibrate_method, cache, target)
    return plan


def _entropy_cache(pre: Path, reader, op_types: list[str] | None) -> Path:
    """Entropy calibration with :data:`ENTROPY_BINS` / :data:`ENTROPY_QUANTIZED_BINS`, saved as
    onnxruntime's calibration cache beside ``pre`` (``quantize_static`` then reads it);
    ``op_types``: the calibrated operators (``None``: every one onnxruntime quantizes)."""
    import inspect

    from onnxruntime.quantization import CalibrationMethod, quantize_static
    from onnxruntime.quantization.calibrate import create_calibrator, save_tensors_data
    from onnxruntime.quantization.registry import QDQRegistry, QLinearOpsRegistry

    if "calibration_cache_path" not in inspect.signature(quantize_static).parameters:
        raise SlimsegError(
            "--calib-method entropy needs an onnxruntime whose quantize_static takes a "
            "calibration cache: pip install -U onnxruntime (or use minmax / percentile)"
        )
    ops = op_types or sorted(set(QLinearOpsRegistry) | set(QDQRegistry))
    calibrator = create_calibrator(
        pre,
        ops,
        augmented_model_path=str(pre.with_suffix(".augmented.onnx")),
        calibrate_method=CalibrationMethod.Entropy,
        extra_options={"num_bins": ENTROPY_BINS, "num_quantized_bins": ENTROPY_QUANTIZED_BINS},
    )
    calibrator.collect_data(reader)
    cache = pre.with_suffix(".entropy.json")
    save_tensors_data(calibrator.compute_data(), cache)
    return cache


def _quantize(
    pre: Path,
    out_path: Path,
    reader,
    plan: Placement,
    calibrate_method,
    cache: Path | None,
    target: str,
) -> None:
    """Q/DQ on every node of ``plan.quantize``, per-channel int8 symmetric weights, in each
    target's form. ``tensorrt``: symmetric int8 activations, float biases, Conv only.
    ``onnxruntime``: U8S8, uint8 asymmetric activations (both-sided percentile ranges too),
    int32 biases, every operator. ``cache``: entropy ranges computed beforehand."""
    from onnxruntime.quantization import QuantFormat, QuantType, quantize_static

    if target == "onnxruntime":
        activation = QuantType.QUInt8
        options = {"ActivationSymmetric": False, "CalibTensorRangeSymmetric": False}
    else:
        activation = QuantType.QInt8
        options = {"ActivationSymmetric": True, "QuantizeBias": False}
    cached = {"calibration_cache_path": str(cache)} if cache else {}
    quantize_static(
        str(pre),
        str(out_path),
        reader,
        quant_format=QuantFormat.QDQ,
        op_types_to_quantize=QUANTIZED_OPS[target],
        nodes_to_quantize=plan.quantize,
        per_channel=True,
        activation_type=activation,
        weight_type=QuantType.QInt8,
        calibrate_method=calibrate_method,
        extra_options={**options, "WeightSymmetric": True},
        **cached,
    )
