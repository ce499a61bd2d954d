"""Forward passes behind :class:`~slimseg.deploy.predictor.Predictor`: a fused torch model or an
onnxruntime session, both mapping a network input ``[B, 3, H, W]`` to ``(pred, proto)``.

``pred``: ``float32 [B, 4 + nc (+ nm), A]`` (``[B, K + 1, H, W]`` logits for semantic models);
``proto``: ``float32 [B, nm, H/s, W/s]`` or ``None``; numpy arrays from both, so what follows
runs without torch (the ONNX runner imports none: the core install).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from slimseg.errors import SlimsegError
from slimseg.utils.threads import torch_threads

if TYPE_CHECKING:
    import torch

# Output names a slimseg export uses, in the order the runners return them.
OUTPUT_NAMES = ("output0", "output1", "logits")


class TorchRunner:
    """Forward pass of a fused eval-mode torch model, with ``threads`` torch threads for the
    duration of each call (the process-wide count is restored afterwards)."""

    def __init__(self, model: torch.nn.Module, threads: int | None = None) -> None:
        self.model = model
        self.threads = threads
        self.dtype = np.float32
        self.batch_size: int | None = None  # any batch

    def __call__(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """``(pred, proto)`` as float32 arrays (``proto`` ``None`` for detection heads)."""
        import torch

        with torch_threads(self.threads), torch.inference_mode():
            out = self.model(torch.from_numpy(x))
        pred, proto = out if isinstance(out, tuple) else (out, None)
        return pred.float().numpy(), None if proto is None else proto.float().numpy()


class PortInfo(Protocol):
    """An input or output of a graph session: onnxruntime's ``NodeArg`` and
    :class:`~slimseg.deploy.ov_session.Port` (``shape``: ints and symbols; ``type`` as
    onnxruntime spells it, ``tensor(float)``)."""

    @property
    def name(self) -> str: ...
    @property
    def shape(self) -> Sequence[Any]: ...
    @property
    def type(self) -> str: ...


class GraphSession(Protocol):
    """What :class:`OnnxRunner` runs: an onnxruntime ``InferenceSession``
    (:func:`~slimseg.deploy.ort_session.cpu_session`) or an
    :class:`~slimseg.deploy.ov_session.OpenVinoSession`."""

    def get_inputs(self) -> Sequence[PortInfo]: ...
    def get_outputs(self) -> Sequence[PortInfo]: ...
    def run(self, output_names: list[str], input_feed: dict[str, np.ndarray]) -> list: ...


def check_single_image_input(session: GraphSession, where: str) -> None:
    """``SlimsegError`` unless the graph takes exactly one input, a float ``[B, 3, H, W]``
    image (a slimseg export): another graph would fail inside onnxruntime at the first frame."""
    inputs = session.get_inputs()
    if len(inputs) != 1:
        names = ", ".join(f"{i.name} {list(i.shape)}" for i in inputs)
        raise SlimsegError(
            f"{where}: the graph takes {len(inputs)} inputs ({names}); a slimseg model takes one "
            "image [B, 3, H, W]: export it with slimseg export"
        )
    inp = inputs[0]
    shape = list(inp.shape)
    if inp.type not in ("tensor(float)", "tensor(float16)") or len(shape) != 4 or shape[1] != 3:
        raise SlimsegError(
            f"{where}: input {inp.name} is {inp.type} {shape}; a slimseg model takes one float "
            "image [B, 3, H, W]: export it with slimseg export"
        )


class OnnxRunner:
    """Forward pass of a graph session: onnxruntime (CPU provider) or OpenVINO (CPU).

    ``dtype``: the input's (``float16`` for FP16 exports); ``batch_size``: the graph's static
    batch, ``None`` when dynamic; ``static_hw``: the static input ``(H, W)`` or ``None``.
    """

    def __init__(self, session: GraphSession, where: str = "the ONNX model") -> None:
        self.session = session
        check_single_image_input(session, where)
        inp = session.get_inputs()[0]
        self.input_name = inp.name
        self.dtype = np.float16 if inp.type == "tensor(float16)" else np.float32
        self.input_shape = list(inp.shape)
        batch = self.input_shape[0] if self.input_shape else None
        self.batch_size = batch if isinstance(batch, int) and batch > 0 else None
        static = self.input_shape[2:4]
        self.static_hw = (
            (int(static[0]), int(static[1]))
            if len(static) == 2 and all(isinstance(d, int) and d > 0 for d in static)
            else None
        )
        names = [o.name for o in session.get_outputs()]
        self.output_names = [n for n in OUTPUT_NAMES if n in names] or names

    def raw(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """The graph's outputs as onnxruntime returns them (float16 for FP16 exports), by name."""
        outs = self.session.run(self.output_names, {self.input_name: x.astype(self.dtype)})
        return dict(zip(self.output_names, outs, strict=True))

    def __call__(
        self, x: np.ndarray, raw: dict[str, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """``(pred, proto)`` as float32 arrays; ``raw``: a dict that also receives the
        outputs as onnxruntime returned them (see :meth:`raw`)."""
        named = self.raw(x)
        if raw is not None:
            raw.update(named)
        outs = list(named.values())
        pred = np.asarray(outs[0], np.float32)
        proto = np.asarray(outs[1], np.float32) if len(outs) > 1 else None
        return pred, proto

    def run_chunked(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`__call__` for any batch: a static-batch graph runs in chunks of its batch
        size (the last one zero-padded, the padding dropped from the outputs)."""
        step = self.batch_size
        if step is None or len(x) == step:
            return self(x)
        preds, protos = [], []
        for s in range(0, len(x), step):
            chunk = x[s : s + step]
            n = len(chunk)
            if n < step:
                chunk = np.concatenate([chunk, np.zeros((step - n, *chunk.shape[1:]), x.dtype)])
            pred, proto = self(chunk)
            preds.append(pred[:n])
            if proto is not None:
                protos.append(proto[:n])
        return np.concatenate(preds), np.concatenate(protos) if protos else None
