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
from slimseg.deploy.tolerances import FP32_TOLERANCES, Tolerance
from slimseg.errors import SlimsegError
from slimseg.utils.extras import install_command
from slimseg.utils.threads import check_threads

log = logging.getLogger(__name__)

OPENVINO_EXTRA = "openvino"
PRECISIONS = ("f32", "bf16", "f16")
DEFAULT_PRECISION = "f32"  # the contract's parity holds at FP32 arithmetic
MATCH_IOU = 0.9  # an end-to-end detection matches f32's: same class, box IoU at least this
CHECK_FRAMES = 2  # frames a bf16 / f16 session also runs at f32, to say how far it is
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
        self._compiled = self._compile(core, model, threads, precision)
        self._inputs = [_port(p) for p in self._compiled.inputs]
        self._outputs = [_port(p) for p in self._compiled.outputs]
        check_graph_outputs(self.path, self.metadata, {o.name: o.shape for o in self._outputs})
        self._request = self._compiled.create_infer_request()
        self._reference = None  # the f32 compile of a bf16 / f16 session, for its first frames
        if precision != DEFAULT_PRECISION:
            self._reference = self._compile(core, model, threads, DEFAULT_PRECISION)
        self._checked = 0

    @staticmethod
    def _compile(core: Any, model: Any, threads: int | None, precision: str) -> Any:
        config: dict[str, Any] = {
            "INFERENCE_PRECISION_HINT": precision,
            "PERFORMANCE_HINT": "LATENCY",
        }
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
        if self._reference is not None and self._checked < CHECK_FRAMES:
            self._checked += 1
            ref_request = self._reference.create_infer_request()
            ref = self._infer(ref_request, output_names, feed)
            self._report(dict(zip(output_names, ref, strict=True)),
                         dict(zip(output_names, got, strict=True)))  # fmt: skip
            if self._checked == CHECK_FRAMES:
                self._reference = None  # its memory back
        return got

    def _infer(self, request: Any, names: list[str], feed: dict[str, np.ndarray]) -> list:
        res = request.infer(feed)
        compiled = request.get_compiled_model()
        return [np.asarray(res[compiled.output(n)]) for n in names]

    def _report(self, ref: dict[str, np.ndarray], got: dict[str, np.ndarray]) -> None:
        """One log line: how far this precision's outputs are from f32's on this frame."""
        head = f"{self.path.name}: OpenVINO {self.precision} vs f32 on frame {self._checked}: "
        if "num_dets" in ref:  # rows may change order: detections matched instead
            matched, total = end2end_matches(ref, got)
            off = matched < total or not np.array_equal(ref["num_dets"], got["num_dets"])
            line = (
                f"{head}{matched} of {total} detections matched (same class, box IoU >= "
                f"{MATCH_IOU}); num_dets {ref['num_dets'].tolist()} -> {got['num_dets'].tolist()}"
            )
        else:
            excess, worst = precision_excess(ref, got, len(self.metadata["names"]))
            off = excess > 1
            line = f"{head}{excess:.2f}x the export's FP32 limits (worst {worst})"
        if off:
            log.warning("%s: the contract's parity holds at f32 only", line)
        else:
            log.info(line)


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
