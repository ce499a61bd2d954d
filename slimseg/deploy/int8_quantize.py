"""FP32 ONNX → symmetric INT8 Q/DQ ONNX with ``onnxruntime.quantization``.

``quant_pre_process`` (shape inference, graph clean-up), then ``quantize_static`` in QDQ format:
per-channel symmetric INT8 weights, per-tensor symmetric INT8 activations (every zero point 0:
TensorRT's parser accepts nothing else), biases left in float (TensorRT rejects onnxruntime's
int32 bias ``DequantizeLinear``), Q/DQ only on the Conv nodes the placement
(:mod:`slimseg.deploy.int8_placement`) selects. The one file runs in onnxruntime on the CPU
and builds a TensorRT engine with explicit quantization (``export/build_engine.sh``).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import onnx
from tqdm import tqdm

from slimseg.deploy.calibration import CalibrationSet
from slimseg.deploy.int8_placement import QUANTIZE_DEPTHWISE, Placement, plan_placement
from slimseg.errors import SlimsegError

log = logging.getLogger(__name__)

# Symmetric per-channel Q/DQ with QuantizeBias=False needs this onnxruntime (or newer).
MIN_ONNXRUNTIME = (1, 17)
CALIB_METHODS = ("minmax", "percentile", "entropy")
MIN_INT8_OPSET = 13  # per-channel QuantizeLinear/DequantizeLinear (axis attribute)


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
    quantize_depthwise: bool = QUANTIZE_DEPTHWISE,
) -> Placement:
    """Write the INT8 Q/DQ graph of ``fp32_path`` to ``out_path``; returns the placement.

    ``out_path``'s folder also receives the pre-processed intermediate (``*.pre.onnx``).
    """
    check_onnxruntime()
    from onnxruntime.quantization import QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    calibrate_method = _calibrate_method(method)
    opset = max(
        o.version for o in onnx.load(str(fp32_path)).opset_import if o.domain in ("", "ai.onnx")
    )
    if opset < MIN_INT8_OPSET:
        raise SlimsegError(f"--int8 needs opset >= {MIN_INT8_OPSET} (got {opset}): pass --opset 18")
    pre = out_path.with_suffix(".pre.onnx")
    quant_pre_process(str(fp32_path), str(pre), skip_symbolic_shape=False)
    plan = plan_placement(onnx.load(str(pre)), family, quantize_depthwise)
    log.info("INT8 placement: %s", plan.summary())
    quantize_static(
        str(pre),
        str(out_path),
        _reader(calib, imgsz, progress),
        quant_format=QuantFormat.QDQ,
        op_types_to_quantize=["Conv"],
        nodes_to_quantize=plan.quantize,
        per_channel=True,
        activation_type=QuantType.QInt8,
        weight_type=QuantType.QInt8,
        calibrate_method=calibrate_method,
        extra_options={
            "ActivationSymmetric": True,
            "WeightSymmetric": True,
            "QuantizeBias": False,
        },
    )
    return plan
