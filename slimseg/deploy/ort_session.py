"""onnxruntime CPU sessions configured the same way everywhere (export parity, predict, bench)."""

from __future__ import annotations

from pathlib import Path

from slimseg.errors import SlimsegError
from slimseg.utils.threads import check_threads


def cpu_session(path: str | Path, threads: int | None = None):
    """An ``InferenceSession`` on the CPU provider with ``threads`` intra-op threads and no
    idle spinning (spinning sessions steal the cores from everything else in the process)."""
    import onnxruntime as ort

    check_threads(threads)  # before a pool of that size exists
    opts = ort.SessionOptions()
    if threads:
        opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    try:
        return ort.InferenceSession(
            str(path), sess_options=opts, providers=["CPUExecutionProvider"]
        )
    except Exception as exc:  # onnxruntime raises its own untyped errors
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise SlimsegError(f"{path}: onnxruntime cannot load it ({msg})") from None
