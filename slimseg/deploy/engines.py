"""The engines that run a slimseg ``.onnx`` on the CPU, behind one call: onnxruntime
(:func:`~slimseg.deploy.ort_session.cpu_session`) and OpenVINO
(:class:`~slimseg.deploy.ov_session.OpenVinoSession`, f32 unless a precision is asked for:
``openvino:bf16``, ``openvino:f16``). docs/engines.md says which file runs best in which."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from slimseg.deploy.metadata import read_session_metadata
from slimseg.deploy.ort_session import cpu_session
from slimseg.deploy.ov_session import DEFAULT_PRECISION, PRECISIONS, OpenVinoSession
from slimseg.deploy.runners import GraphSession
from slimseg.errors import SlimsegError

#: what ``--backend`` takes for an ``.onnx`` file: an engine, or OpenVINO at a precision
ONNX_BACKENDS = (
    "onnxruntime",
    "openvino",
    *(f"openvino:{p}" for p in PRECISIONS if p != DEFAULT_PRECISION),
)


def open_graph(
    path: str | Path, threads: int | None = None, backend: str = "onnxruntime"
) -> tuple[GraphSession, dict[str, Any], str]:
    """``(session, metadata, backend)``: ``path`` loaded by ``backend`` (one of
    :data:`ONNX_BACKENDS`) with ``threads`` intra-op threads; the export's metadata, checked
    against the graph's outputs; the backend's name (``openvino`` for OpenVINO at f32)."""
    if backend not in ONNX_BACKENDS:
        raise SlimsegError(
            f"{path}: backend {backend!r} does not run .onnx files; choose one of "
            f"{', '.join(ONNX_BACKENDS)}"
        )
    if backend == "onnxruntime":
        session = cpu_session(path, threads)
        return session, read_session_metadata(path, session), backend
    precision = backend.partition(":")[2] or DEFAULT_PRECISION
    ov = OpenVinoSession(path, threads, precision)
    return ov, ov.metadata, "openvino" if precision == DEFAULT_PRECISION else backend
