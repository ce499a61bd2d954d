"""Inference on single frames: one API over onnxruntime or OpenVINO (``.onnx``) and torch
(``.pt``/``.ckpt``).

Both backends share every step but the forward pass, so the same weights give the same
detections (up to float rounding) whichever file is loaded:

1. preprocess (:mod:`slimseg.deploy.preprocess`): the shared letterbox to the model's input
   size, RGB / 255, NCHW, float32 (float16 for FP16 exports, as their metadata says);
2. inference (:mod:`slimseg.deploy.runners`): the fused model or the ONNX graph →
   ``pred [B, 4 + nc (+ nm), A]`` and, for segmenters, ``proto [B, nm, H/s, W/s]``;
3. postprocess (:mod:`slimseg.deploy.predict_postprocess`, numpy): NMS, boxes and masks on
   the source frame; semantic models (``logits [B, K+1, H, W]``) get a class map instead.
   End-to-end exports (metadata ``end2end``: NMS and mask product inside the graph) skip the
   NMS (:mod:`slimseg.deploy.end2end_postprocess`).

The ONNX backend imports no torch (the core install, ``pip install slimseg``); ``.pt``/``.ckpt``
weights need the ``train`` extra.

Class names, mobility priors, input size and precision come from the ONNX metadata written by
``slimseg export`` (:func:`~slimseg.deploy.metadata.read_session_metadata`), or from the weights
file for torch, where the same metadata dict is built with
:func:`~slimseg.deploy.metadata.build_metadata`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from slimseg.deploy.end2end_postprocess import end2end_limits, end2end_predictions, is_end2end
from slimseg.deploy.engines import ONNX_BACKENDS, open_graph
from slimseg.deploy.metadata import build_metadata, int8_target
from slimseg.deploy.predict_postprocess import instance_predictions, semantic_predictions
from slimseg.deploy.prediction import combined_mask
from slimseg.deploy.preprocess import parse_imgsz, preprocess_frame
from slimseg.deploy.runners import OnnxRunner, TorchRunner
from slimseg.detections import Prediction
from slimseg.errors import SlimsegError
from slimseg.ops.nms_numpy import MAX_DET, NMS_IOU, PREDICT_CONF
from slimseg.utils.threads import check_threads, torch_threads

__all__ = ["BACKENDS", "BACKEND_CHOICES", "Prediction", "Predictor", "combined_mask"]

BACKENDS = ("auto", "onnxruntime", "openvino", "torch")
# what --backend / backend= accepts: a backend, or openvino at a precision it is asked for
BACKEND_CHOICES = ("auto", *ONNX_BACKENDS, "torch")
# What a forward pass gives: (pred, proto) of a raw graph, or an end-to-end graph's outputs by name
Outputs = tuple[np.ndarray, np.ndarray | None] | dict[str, np.ndarray]
TORCH_SUFFIXES = (".pt", ".ckpt")


class Predictor:
    """A loaded model plus its metadata; :meth:`predict` maps an RGB frame to a
    :class:`Prediction`. Build it with :meth:`from_path`."""

    def __init__(
        self,
        runner: TorchRunner | OnnxRunner,
        metadata: dict[str, Any],
        imgsz: tuple[int, int],
        backend: str,
        path: Path | None = None,
        threads: int | None = None,
    ) -> None:
        self.runner = runner
        self.threads = threads
        """intra-op threads of the network (None: the library's default)"""
        self.metadata = metadata
        self.imgsz = imgsz
        self.backend = backend
        self.path = path
        self.names: list[str] = [str(n) for n in metadata["names"]]
        self.mobility: list[float] = [float(m) for m in metadata["mobility"]]
        self.family: str = metadata["family"]
        self.task: str = metadata["task"]
        self.num_classes = len(self.names)
        self.input_dtype = runner.dtype
        self.end2end = is_end2end(metadata)
        """an end-to-end export: NMS and the mask product ran inside the graph"""

    @property
    def precision(self) -> str:
        """``fp32``, ``fp16`` or ``int8`` (the export's metadata; the input dtype otherwise)."""
        declared = self.metadata.get("precision")
        if declared in ("fp32", "fp16", "int8"):
            return declared
        return "fp16" if self.input_dtype == np.float16 else "fp32"

    @property
    def int8_target(self) -> str | None:
        """``tensorrt`` or ``onnxruntime`` for an INT8 export (its metadata), else ``None``."""
        return int8_target(self.metadata)

    def __repr__(self) -> str:
        target = f" for {self.int8_target}" if self.int8_target else ""
        target += ", end-to-end" if self.end2end else ""
        return (
            f"Predictor({self.metadata.get('model', '?')}, backend={self.backend}, "
            f"imgsz={list(self.imgsz)}, {self.precision}{target}, {self.num_classes} classes)"
        )

    @classmethod
    def from_path(
        cls,
        path: str | Path,
        backend: str = "auto",
        imgsz: int | Sequence[int] | None = None,
        threads: int | None = None,
    ) -> Predictor:
        """Load ``.onnx`` (onnxruntime or OpenVINO, CPU) or ``.pt``/``.ckpt`` (torch, fused).

        ``backend``: ``auto`` (onnxruntime for ``.onnx``, torch otherwise), ``onnxruntime``,
        ``torch``, or ``openvino`` (f32 arithmetic, the contract's; ``openvino:bf16`` /
        ``openvino:f16`` compute in that precision and log how far the first frames are from
        f32: :mod:`slimseg.deploy.ov_session`).

        ``imgsz``: network input ``H`` or ``(H, W)``; default: the metadata's (ONNX) or the
        training size (torch, 640 if unknown). A static ONNX graph only runs at its own size.
        ``threads``: intra-op threads (the onnxruntime session's; for torch, the count set
        around each forward pass and restored after it). ``None``: the library default.
        """
        path = Path(path)
        if backend not in BACKEND_CHOICES:
            raise SlimsegError(
                f"unknown backend {backend!r}; choose one of {', '.join(BACKEND_CHOICES)}"
            )
        if not path.is_file():
            raise SlimsegError(f"{path}: model file not found")
        suffix = path.suffix.lower()
        if suffix not in (".onnx", *TORCH_SUFFIXES):
            raise SlimsegError(f"{path}: expected an .onnx, .pt or .ckpt file")
        if backend == "auto":
            backend = "onnxruntime" if suffix == ".onnx" else "torch"
        if backend in ONNX_BACKENDS and suffix != ".onnx":
            raise SlimsegError(f"{path}: the {backend} backend needs an .onnx file")
        if backend == "torch" and suffix == ".onnx":
            raise SlimsegError(f"{path}: the torch backend needs .pt/.ckpt weights")
        hw = parse_imgsz(imgsz)
        if threads is not None and threads < 1:
            raise SlimsegError(f"threads must be >= 1, got {threads}")
        check_threads(threads)  # no more than the cores this process may use
        if backend == "torch":
            return cls._from_torch(path, hw, threads)
        return cls._from_onnx(path, hw, threads, backend)

    @classmethod
    def _from_torch(cls, path: Path, hw: tuple[int, int] | None, threads: int | None) -> Predictor:
        from slimseg.utils.extras import needs_train

        with needs_train(f"loading {path.suffix} weights"):
            from slimseg.models.checkpoint import load_weights

        with torch_threads(threads):
            model, info = load_weights(path, fused=True)
        if hw is None:
            trained = info.train_config.get("imgsz", 640)
            hw = parse_imgsz(trained if isinstance(trained, int) else list(trained))
        meta = build_metadata(model, info.names, info.mobility, hw)
        return cls(TorchRunner(model, threads), meta, hw, "torch", path, threads)

    @classmethod
    def _from_onnx(
        cls, path: Path, hw: tuple[int, int] | None, threads: int | None, backend: str
    ) -> Predictor:
        """``backend``: one of :data:`~slimseg.deploy.engines.ONNX_BACKENDS`."""
        session, meta, backend = open_graph(path, threads, backend)
        runner = OnnxRunner(session, str(path))
        static_hw = runner.static_hw
        default = static_hw or parse_imgsz(meta["imgsz"])
        if hw is not None and static_hw is not None and hw != static_hw:
            raise SlimsegError(
                f"{path}: the graph has a static {static_hw[0]}x{static_hw[1]} input; "
                f"imgsz {hw[0]}x{hw[1]} needs an export with --dynamic (or drop --imgsz)"
            )
        return cls(runner, meta, hw or default, backend, path, threads)

    # -- inference ---------------------------------------------------------------------------

    def preprocess(self, image_rgb: np.ndarray) -> tuple[np.ndarray, dict]:
        """``uint8 [h, w, 3]`` RGB → ``[1, 3, H, W]`` network input and its letterbox meta."""
        return preprocess_frame(image_rgb, self.imgsz, self.input_dtype)

    def _forward(self, x: np.ndarray, raw: dict[str, np.ndarray] | None = None) -> Outputs:
        """The network on ``x``: ``(pred, proto)``, or the named outputs of an end-to-end
        graph; ``raw`` receives the outputs as onnxruntime returned them."""
        if self.end2end and isinstance(self.runner, OnnxRunner):
            named = self.runner.raw(x)
            if raw is not None:
                raw.update(named)
            return named
        return self.runner(x, raw) if raw is not None else self.runner(x)

    def _postprocess(
        self,
        outputs: Outputs,
        metas: Sequence[dict],
        conf: float,
        iou: float,
        max_det: int,
    ) -> list[Prediction]:
        if isinstance(outputs, dict):
            end2end_limits(self.metadata, conf, iou, str(self.path))
            return end2end_predictions(
                outputs, metas, self.names, self.mobility, conf, max_det
            )  # fmt: skip
        pred, proto = outputs
        if self.task == "semantic":
            return semantic_predictions(pred, metas, self.names)
        return instance_predictions(
            pred, proto, metas, self.names, self.mobility, self.family, conf, iou, max_det
        )

    def predict(
        self,
        image_rgb: np.ndarray,
        conf: float = PREDICT_CONF,
        iou: float = NMS_IOU,
        max_det: int = MAX_DET,
        raw: dict[str, np.ndarray] | None = None,
    ) -> Prediction:
        """Detect (and segment) one RGB ``uint8 [h, w, 3]`` frame; results on that frame.

        ``conf``: keep scores above it; ``iou``: class-aware NMS threshold; ``max_det``: cap.
        ``raw`` (ONNX models): a dict that receives the network input ``images`` and the
        outputs exactly as onnxruntime returned them (``output0``, ``output1`` or ``logits``;
        float16 for FP16 exports), what a C++ runtime gets (``slimseg predict --dump-raw``).
        """
        if raw is not None and not isinstance(self.runner, OnnxRunner):
            raise SlimsegError(
                f"{self.path}: raw outputs come from an exported .onnx model, not {self.backend}"
            )
        t0 = time.perf_counter()
        x, meta = self.preprocess(image_rgb)
        t1 = time.perf_counter()
        if raw is not None:
            raw["images"] = x
        outputs = self._forward(x, raw)
        t2 = time.perf_counter()
        (result,) = self._postprocess(outputs, [meta], conf, iou, max_det)
        t3 = time.perf_counter()
        result.timings = {
            "preprocess": 1000 * (t1 - t0),
            "inference": 1000 * (t2 - t1),
            "postprocess": 1000 * (t3 - t2),
        }
        return result

    def predict_batch(
        self,
        images_rgb: Sequence[np.ndarray],
        conf: float = PREDICT_CONF,
        iou: float = NMS_IOU,
        max_det: int = MAX_DET,
    ) -> list[Prediction]:
        """:meth:`predict` for several frames (any sizes) in one forward pass per chunk.

        Static-batch ONNX graphs run in chunks of their batch size. Each prediction's
        ``timings`` is its chunk's time divided by the chunk size.
        """
        step = self.runner.batch_size or max(len(images_rgb), 1)
        out: list[Prediction] = []
        for s in range(0, len(images_rgb), step):
            chunk = images_rgb[s : s + step]
            t0 = time.perf_counter()
            inputs = [self.preprocess(im) for im in chunk]
            x = np.concatenate([i[0] for i in inputs])
            if self.runner.batch_size and len(chunk) < self.runner.batch_size:
                pad = self.runner.batch_size - len(chunk)
                x = np.concatenate([x, np.zeros((pad, *x.shape[1:]), x.dtype)])
            t1 = time.perf_counter()
            outputs = self._forward(x)
            t2 = time.perf_counter()
            n = len(chunk)
            if isinstance(outputs, dict):
                outputs = {k: v[:n] for k, v in outputs.items()}
            else:
                outputs = outputs[0][:n], None if outputs[1] is None else outputs[1][:n]
            results = self._postprocess(outputs, [i[1] for i in inputs], conf, iou, max_det)
            t3 = time.perf_counter()
            for r in results:
                r.timings = {
                    "preprocess": 1000 * (t1 - t0) / n,
                    "inference": 1000 * (t2 - t1) / n,
                    "postprocess": 1000 * (t3 - t2) / n,
                }
            out.extend(results)
        return out
