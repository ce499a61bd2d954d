"""OpenVINO (CPU) as a runtime beside onnxruntime, reading the slimseg ``.onnx`` directly.

:class:`OpenVinoSession` offers what :class:`~slimseg.deploy.runners.OnnxRunner` asks of a
graph session (:class:`~slimseg.deploy.runners.GraphSession`: ``get_inputs``, ``get_outputs``,
``run``), so the Predictor, ``slimseg.Masker`` and every command run the same pre- and
post-processing on either engine.

Precision (export/CONTRACT.md "Precision"): OpenVINO's CPU plugin computes in bf16 by default on
CPUs with AVX512_BF16 or AMX, in f16 on ARM and in f32 elsewhere, so the same file gives other
masks on other robots. The session sets ``INFERENCE_PRECISION_HINT`` explicitly: ``f32`` (the
precision the contract's parity holds at) unless ``bf16`` / ``f16`` is asked for; then the first
:data:`CHECK_FRAMES` frames also run at f32 and one log line says by how much the outputs differ,
in multiples of the export's FP32 limits (:mod:`slimseg.deploy.tolerances`).

INT8 Q/DQ files: OpenVINO computes signed int8 activation Q/DQ feeding a requantized ``Concat``
wrongly (the ``tensorrt``-target file), so the session gives it the same arithmetic with uint8
activations (:mod:`slimseg.deploy.qdq_unsigned`). Its INT8 kernels may still not compute a file
as written on some CPU (without VNNI they saturate: docs/engines.md), so the first
:data:`CHECK_FRAMES` frames also run the file's Q/DQ in float; kernels that lose the candidate
detections are replaced by that float path for the session, with one log line
(:mod:`slimseg.deploy.ov_checks`).

The ``.onnx`` is read as it is (no ``ovc`` / ``save_model`` IR: both store FP16 weights by
default). Outputs are looked up by the contract's names (``output0``, ``num_dets``, ...):
OpenVINO may give a port several names and ``get_any_name()`` an internal one.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from slimseg.deploy.end2end_postprocess import END2END_OUTPUTS
from slimseg.deploy.metadata import check_graph_outputs, read_onnx_metadata
from slimseg.deploy.ov_checks import CHECK_FRAMES, check_int8_kernels, check_precision
from slimseg.errors import SlimsegError
from slimseg.utils.extras import install_command
from slimseg.utils.threads import check_threads

log = logging.getLogger(__name__)

OPENVINO_EXTRA = "openvino"
PRECISIONS = ("f32", "bf16", "f16")
DEFAULT_PRECISION = "f32"  # the contract's parity holds at FP32 arithmetic
# the names a slimseg graph's outputs have (the contract's), in lookup order
CONTRACT_OUTPUTS = ("output0", "output1", "logits", *END2END_OUTPUTS)
# OpenVINO element types in onnxruntime's spelling (what OnnxRunner reads)
_TYPES = {"f32": "tensor(float)", "f16": "tensor(float16)", "i32": "tensor(int32)",
          "i64": "tensor(int64)", "boolean": "tensor(bool)"}  # fmt: skip


@dataclass(frozen=True)
class Port:
    """An input or output as :class:`~slimseg.deploy.runners.GraphSession` describes it:
    ``shape`` holds ints (static) and ``"?"`` (dynamic); ``type`` as onnxruntime spells it."""

    name: str
    shape: list[int | str]
    type: str


def _import_openvino() -> Any:
    try:
        import openvino
    except ModuleNotFoundError:
        raise SlimsegError(
            f"--backend openvino needs OpenVINO: {install_command(OPENVINO_EXTRA)}"
        ) from None
    return openvino


def _port(port: Any) -> Port:
    names = port.get_names()
    name = next((n for n in CONTRACT_OUTPUTS if n in names), None) or port.get_any_name()
    shape = [d.get_length() if d.is_static else "?" for d in port.get_partial_shape()]
    kind = port.get_element_type().get_type_name()
    return Port(name, shape, _TYPES.get(kind, f"tensor({kind})"))


class OpenVinoSession:
    """A slimseg ``.onnx`` compiled by OpenVINO for the CPU at ``precision`` (``f32``,
    ``bf16``, ``f16``) with ``threads`` inference threads (None: OpenVINO's default);
    ``metadata``: the export's, checked against the graph's outputs."""

    def __init__(
        self, path: str | Path, threads: int | None = None, precision: str = DEFAULT_PRECISION
    ) -> None:
        if precision not in PRECISIONS:
            raise SlimsegError(
                f"OpenVINO precision {precision!r}: choose one of {', '.join(PRECISIONS)}"
            )
        check_threads(threads)
        ov = _import_openvino()
        self.path = Path(path)
        self.precision = precision
        core = ov.Core()
        try:
            model = core.read_model(str(self.path))
        except RuntimeError as exc:
            msg = str(exc).splitlines()[0] if str(exc) else "unreadable"
            raise SlimsegError(f"{self.path}: OpenVINO cannot read it ({msg})") from None
        # the ONNX metadata_props
        framework = model.get_rt_info()["framework"] if model.has_rt_info(["framework"]) else {}
        props = {str(k): v.astype(str) for k, v in framework.items()}
        self.metadata = read_onnx_metadata(self.path, props)
        self.unsigned_qdq = 0
        """signed activation Q/DQ nodes given to OpenVINO as their uint8 equivalent"""
        if self.metadata.get("precision") == "int8":
            model = self._unsigned(core, model)
        self._compiled = self._compile(core, model, threads, precision)
        self._inputs = [_port(p) for p in self._compiled.inputs]
        self._outputs = [_port(p) for p in self._compiled.outputs]
        check_graph_outputs(self.path, self.metadata, {o.name: o.shape for o in self._outputs})
        self._request = self._compiled.create_infer_request()
        self.int8_kernels = self.metadata.get("precision") == "int8"
        """INT8 Q/DQ run by OpenVINO's INT8 kernels (False: emulated in float, after the
        first frames showed the kernels far from the file's arithmetic on this CPU)"""
        # the first frames also run a reference compile: for an INT8 file its Q/DQ as written
        # (no low-precision transformations) at f32, for a bf16 / f16 session f32
        self._reference: Any = None
        if self.int8_kernels:
            self._reference = self._compile(core, model, threads, DEFAULT_PRECISION, True)
        elif precision != DEFAULT_PRECISION:
            self._reference = self._compile(core, model, threads, DEFAULT_PRECISION)
        self._int8_check = self.int8_kernels
        self._checked = 0

    def _unsigned(self, core: Any, model: Any) -> Any:
        """``model`` with its signed activation Q/DQ as the same uint8 arithmetic
        (:mod:`slimseg.deploy.qdq_unsigned`: OpenVINO computes the signed form wrongly)."""
        import onnx  # the openvino extra's; the core install never imports it

        from slimseg.deploy.qdq_unsigned import unsigned_activations

        proto = onnx.load(str(self.path))
        self.unsigned_qdq = unsigned_activations(proto)
        if not self.unsigned_qdq:
            return model
        log.info("%s: %d signed int8 activation Q/DQ nodes given to OpenVINO as the same uint8 "
                 "arithmetic", self.path.name, self.unsigned_qdq)  # fmt: skip
        return core.read_model(proto.SerializeToString())

    @staticmethod
    def _compile(
        core: Any, model: Any, threads: int | None, precision: str, exact_qdq: bool = False
    ) -> Any:
        """``exact_qdq``: Q/DQ pairs computed as written, in float (OpenVINO's
        low-precision transformations off: no INT8 kernels; slower)."""
        config: dict[str, Any] = {
            "INFERENCE_PRECISION_HINT": precision,
            "PERFORMANCE_HINT": "LATENCY",
        }
        if exact_qdq:
            config["LP_TRANSFORMS_MODE"] = False
        if threads:
            config["INFERENCE_NUM_THREADS"] = threads
        return core.compile_model(model, "CPU", config)

    def get_inputs(self) -> list[Port]:
        return list(self._inputs)

    def get_outputs(self) -> list[Port]:
        return list(self._outputs)

    def run(self, output_names: list[str], feed: dict[str, np.ndarray]) -> list[np.ndarray]:
        """The outputs ``output_names`` for the inputs ``feed`` (name -> array), as
        onnxruntime's ``InferenceSession.run`` returns them."""
        got = self._infer(self._request, output_names, feed)
        if self._reference is None:
            return got
        self._checked += 1
        ref_request = self._reference.create_infer_request()
        ref = self._infer(ref_request, output_names, feed)
        named = [dict(zip(output_names, o, strict=True)) for o in (ref, got)]
        what = f"{self.path.name}: OpenVINO ({self.precision})"
        if self._int8_check:
            if not check_int8_kernels(what, self._checked, *named, self.metadata, self.precision):
                # from now on the Q/DQ as written: right, if slower
                self._request, self.int8_kernels, got = ref_request, False, ref
                self._checked = CHECK_FRAMES
        else:
            check_precision(what, self._checked, *named, self.metadata)
        if self._checked >= CHECK_FRAMES:
            self._reference = None  # its memory back (or now in self._request)
        return got

    def _infer(self, request: Any, names: list[str], feed: dict[str, np.ndarray]) -> list:
        res = request.infer(feed)
        compiled = request.get_compiled_model()
        return [np.asarray(res[compiled.output(n)]) for n in names]
