"""Inference on single frames: one API over onnxruntime (``.onnx``) and torch (``.pt``/``.ckpt``).

Both backends share every step but the forward pass, so the same weights give the same
detections (up to float rounding) whichever file is loaded:

1. preprocess: the shared letterbox (:mod:`slimseg.data.letterbox`) to the model's input size,
   RGB / 255, NCHW, float32 (float16 for FP16 exports, as their metadata says);
2. inference: the fused model or the ONNX graph → ``pred [B, 4 + nc (+ nm), A]`` and, for
   segmenters, ``proto [B, nm, H/4, W/4]`` (Darknet YOLOv3 rows go through
   :func:`~slimseg.ops.nms.yolov3_to_rows`);
3. postprocess: :func:`~slimseg.ops.nms.non_max_suppression`, then
   :func:`~slimseg.eval.postprocess.to_frame_detections` (boxes and masks on the source frame).
   Semantic models (MSNET, output ``logits [B, K+1, H, W]``) skip NMS: the logits are cropped
   to the letterbox content, resized to the frame and argmaxed into
   :attr:`Prediction.class_map` (:func:`~slimseg.ops.semantic.logits_to_frame`).

Class names, mobility priors, input size and precision come from the ONNX metadata written by
``slimseg export`` (see :mod:`slimseg.deploy.metadata`), or from the weights file for torch,
where the same metadata dict is built with :func:`~slimseg.deploy.metadata.build_metadata`.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from slimseg.data.letterbox import LetterboxParams, letterbox_image, letterbox_params
from slimseg.deploy.metadata import build_metadata
from slimseg.deploy.ort_session import cpu_session
from slimseg.errors import SlimsegError
from slimseg.eval.postprocess import to_frame_detections
from slimseg.ops.nms import non_max_suppression, yolov3_to_rows
from slimseg.ops.semantic import logits_to_frame

BACKENDS = ("auto", "onnxruntime", "torch")
TORCH_SUFFIXES = (".pt", ".ckpt")
MAX_STRIDE = 32
# Keys every slimseg export carries and the predictor cannot do without.
REQUIRED_METADATA = ("names", "imgsz", "family", "task")


@dataclass(eq=False)
class Prediction:
    """Detections of one frame in source-frame pixels, sorted by decreasing score.

    ``boxes``: ``float32 [N, 4]`` xyxy, clipped to the frame; ``scores``: ``float32 [N]``;
    ``classes``: ``int64 [N]``; ``names`` and ``mobility``: the class name and mobility prior
    of each detection; ``masks``: ``bool [N, h, w]`` (``None`` for detection-only models);
    ``image_hw``: ``(h, w)``; ``timings``: milliseconds spent in ``preprocess``,
    ``inference`` and ``postprocess``.

    Semantic models (MSNET) have no detections (empty ``boxes``/``scores``/``classes``,
    ``masks`` ``None``); their output is ``class_map``: ``uint8 [h, w]`` on the source frame,
    ``0`` = background, ``k + 1`` = class ``k`` (``int32`` if a model had over 254 classes).
    It is ``None`` for detectors and instance segmenters. ``class_names``: the model's class
    names (``class_names[k]`` is value ``k + 1`` of ``class_map``; empty for the others).
    """

    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray
    names: list[str]
    mobility: list[float]
    masks: np.ndarray | None
    image_hw: tuple[int, int]
    timings: dict[str, float] = field(default_factory=dict)
    class_map: np.ndarray | None = None
    class_names: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.scores)

    def detections(self) -> list[dict[str, Any]]:
        """JSON-ready detections: ``box`` xyxy, ``class``, ``name``, ``score``, ``mobility``."""
        return [
            {
                "box": [round(float(v), 2) for v in box],
                "class": int(cls),
                "name": name,
                "score": round(float(score), 5),
                "mobility": float(mob),
            }
            for box, cls, name, score, mob in zip(
                self.boxes, self.classes, self.names, self.scores, self.mobility, strict=True
            )
        ]


def combined_mask(prediction: Prediction, classes: Iterable[int | str] | None = None) -> np.ndarray:
    """``uint8 [h, w]``: 255 where any selected detection is, 0 elsewhere (a SLAM mask).

    ``classes``: class ids or names to keep (``None``: all), e.g. a model's
    ``metadata["dynamic_classes"]``. Detection-only predictions (no masks) fill their boxes;
    semantic predictions mark the pixels of the selected classes in their ``class_map``.
    """
    h, w = prediction.image_hw
    out = np.zeros((h, w), np.uint8)
    if prediction.class_map is not None:
        if classes is None:
            out[prediction.class_map > 0] = 255
            return out
        labels = prediction.class_names
        ids = [
            int(c) + 1 if not isinstance(c, str) else labels.index(c) + 1
            for c in classes
            if not isinstance(c, str) or c in labels
        ]
        out[np.isin(prediction.class_map, ids)] = 255
        return out
    keep = np.ones(len(prediction), bool)
    if classes is not None:
        wanted = set(classes)
        pairs = zip(prediction.classes, prediction.names, strict=True)
        keep = np.array([int(c) in wanted or n in wanted for c, n in pairs], bool).reshape(-1)
    if not keep.any():
        return out
    if prediction.masks is not None:
        out[prediction.masks[keep].any(axis=0)] = 255
        return out
    for x1, y1, x2, y2 in prediction.boxes[keep]:
        # Pixels whose centre lies in the box (the rule masks are cropped with).
        c0, r0 = int(np.ceil(x1 - 0.5)), int(np.ceil(y1 - 0.5))
        c1, r1 = int(np.ceil(x2 - 0.5)), int(np.ceil(y2 - 0.5))
        out[max(r0, 0) : max(r1, 0), max(c0, 0) : max(c1, 0)] = 255
    return out


class _TorchRunner:
    """Forward pass of a fused eval-mode torch model."""

    def __init__(self, model: torch.nn.Module) -> None:
        self.model = model
        self.dtype = np.float32
        self.batch_size: int | None = None  # any batch

    @torch.inference_mode()
    def __call__(self, x: np.ndarray) -> tuple[torch.Tensor, torch.Tensor | None]:
        out = self.model(torch.from_numpy(x))
        pred, proto = out if isinstance(out, tuple) else (out, None)
        return pred, proto


class _OnnxRunner:
    """Forward pass of an onnxruntime session (CPU provider)."""

    def __init__(self, session: Any) -> None:
        self.session = session
        inp = session.get_inputs()[0]
        self.input_name = inp.name
        self.dtype = np.float16 if inp.type == "tensor(float16)" else np.float32
        self.input_shape = list(inp.shape)
        batch = self.input_shape[0] if self.input_shape else None
        self.batch_size = batch if isinstance(batch, int) and batch > 0 else None
        names = [o.name for o in session.get_outputs()]
        self.output_names = [n for n in ("output0", "output1", "logits") if n in names] or names

    def __call__(self, x: np.ndarray) -> tuple[torch.Tensor, torch.Tensor | None]:
        outs = self.session.run(self.output_names, {self.input_name: x})
        pred = torch.from_numpy(np.asarray(outs[0], np.float32))
        proto = torch.from_numpy(np.asarray(outs[1], np.float32)) if len(outs) > 1 else None
        return pred, proto


def _parse_imgsz(imgsz: int | Sequence[int] | None) -> tuple[int, int] | None:
    if imgsz is None:
        return None
    if isinstance(imgsz, int):
        hw = (imgsz, imgsz)
    else:
        values = [int(v) for v in imgsz]
        if len(values) not in (1, 2):
            raise SlimsegError(f"imgsz must be H or (H, W), got {list(values)}")
        hw = (values[0], values[-1])
    if min(hw) <= 0 or hw[0] % MAX_STRIDE or hw[1] % MAX_STRIDE:
        raise SlimsegError(f"imgsz {list(hw)} must be positive multiples of {MAX_STRIDE}")
    return hw


def read_onnx_metadata(path: Path, props: dict[str, str]) -> dict[str, Any]:
    """Parse ``metadata_props`` of an ONNX file; :class:`SlimsegError` unless slimseg wrote them."""
    meta: dict[str, Any] = {}
    for key, value in props.items():
        try:
            meta[key] = json.loads(value)
        except (TypeError, ValueError):
            meta[key] = value  # not JSON: not ours, checked below
    missing = [k for k in REQUIRED_METADATA if k not in meta]
    names, imgsz = meta.get("names"), meta.get("imgsz")
    if (
        missing
        or not isinstance(names, list)
        or not all(isinstance(n, str) for n in names)
        or not (isinstance(imgsz, list) and len(imgsz) == 2)
    ):
        what = f"missing {', '.join(missing)}" if missing else "malformed names/imgsz"
        raise SlimsegError(
            f"{path}: no slimseg metadata ({what}): not exported by slimseg export; "
            "re-export it with `slimseg export --weights W.pt`, or predict from the .pt weights"
        )
    nc = len(names)
    mobility = meta.get("mobility")
    if not isinstance(mobility, list) or len(mobility) != nc:
        meta["mobility"] = [1.0] * nc
    return meta


class Predictor:
    """A loaded model plus its metadata; :meth:`predict` maps an RGB frame to a
    :class:`Prediction`. Build it with :meth:`from_path`."""

    def __init__(
        self,
        runner: _TorchRunner | _OnnxRunner,
        metadata: dict[str, Any],
        imgsz: tuple[int, int],
        backend: str,
        path: Path | None = None,
    ) -> None:
        self.runner = runner
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

    @property
    def precision(self) -> str:
        return "fp16" if self.input_dtype == np.float16 else "fp32"

    def __repr__(self) -> str:
        return (
            f"Predictor({self.metadata.get('model', '?')}, backend={self.backend}, "
            f"imgsz={list(self.imgsz)}, {self.precision}, {self.num_classes} classes)"
        )

    @classmethod
    def from_path(
        cls,
        path: str | Path,
        backend: str = "auto",
        imgsz: int | Sequence[int] | None = None,
        threads: int | None = None,
    ) -> Predictor:
        """Load ``.onnx`` (onnxruntime, CPU) or ``.pt``/``.ckpt`` (torch, fused) weights.

        ``imgsz``: network input ``H`` or ``(H, W)``; default: the metadata's (ONNX) or the
        training size (torch, 640 if unknown). A static ONNX graph only runs at its own size.
        ``threads``: intra-op threads (onnxruntime session; for torch this sets
        ``torch.set_num_threads``, which is process-wide). ``None``: the library default.
        """
        path = Path(path)
        if backend not in BACKENDS:
            raise SlimsegError(f"unknown backend {backend!r}; choose one of {', '.join(BACKENDS)}")
        if not path.is_file():
            raise SlimsegError(f"{path}: model file not found")
        suffix = path.suffix.lower()
        if suffix not in (".onnx", *TORCH_SUFFIXES):
            raise SlimsegError(f"{path}: expected an .onnx, .pt or .ckpt file")
        if backend == "auto":
            backend = "onnxruntime" if suffix == ".onnx" else "torch"
        if backend == "onnxruntime" and suffix != ".onnx":
            raise SlimsegError(f"{path}: the onnxruntime backend needs an .onnx file")
        if backend == "torch" and suffix == ".onnx":
            raise SlimsegError(f"{path}: the torch backend needs .pt/.ckpt weights")
        hw = _parse_imgsz(imgsz)
        if threads is not None and threads < 1:
            raise SlimsegError(f"threads must be >= 1, got {threads}")
        if backend == "torch":
            return cls._from_torch(path, hw, threads)
        return cls._from_onnx(path, hw, threads)

    @classmethod
    def _from_torch(cls, path: Path, hw: tuple[int, int] | None, threads: int | None) -> Predictor:
        from slimseg.deploy.checkpoint import load_weights

        if threads:
            torch.set_num_threads(threads)
        model, info = load_weights(path, fused=True)
        if hw is None:
            trained = info.train_config.get("imgsz", 640)
            hw = _parse_imgsz(trained if isinstance(trained, int) else list(trained))
        meta = build_metadata(model, info.names, info.mobility, hw)
        return cls(_TorchRunner(model), meta, hw, "torch", path)

    @classmethod
    def _from_onnx(cls, path: Path, hw: tuple[int, int] | None, threads: int | None) -> Predictor:
        session = cpu_session(path, threads)
        meta = read_onnx_metadata(path, dict(session.get_modelmeta().custom_metadata_map))
        runner = _OnnxRunner(session)
        static = runner.input_shape[2:4]
        static_hw = (
            (int(static[0]), int(static[1]))
            if len(static) == 2 and all(isinstance(d, int) and d > 0 for d in static)
            else None
        )
        default = static_hw or _parse_imgsz(meta["imgsz"])
        if hw is not None and static_hw is not None and hw != static_hw:
            raise SlimsegError(
                f"{path}: the graph has a static {static_hw[0]}x{static_hw[1]} input; "
                f"imgsz {hw[0]}x{hw[1]} needs an export with --dynamic (or drop --imgsz)"
            )
        return cls(runner, meta, hw or default, "onnxruntime", path)

    # -- inference ---------------------------------------------------------------------------

    def preprocess(self, image_rgb: np.ndarray) -> tuple[np.ndarray, dict]:
        """``uint8 [h, w, 3]`` RGB → ``[1, 3, H, W]`` network input and its letterbox meta."""
        if (
            not isinstance(image_rgb, np.ndarray)
            or image_rgb.dtype != np.uint8
            or image_rgb.ndim != 3
            or image_rgb.shape[2] != 3
        ):
            got = (
                f"{image_rgb.dtype} {image_rgb.shape}"
                if isinstance(image_rgb, np.ndarray)
                else type(image_rgb).__name__
            )
            raise ValueError(f"expected an RGB uint8 image [h, w, 3], got {got}")
        h, w = image_rgb.shape[:2]
        p: LetterboxParams = letterbox_params(h, w, *self.imgsz)
        boxed = letterbox_image(image_rgb, p)
        # Division (not a multiply by 1/255): bit-identical to the training collate.
        x = boxed.transpose(2, 0, 1)[None].astype(np.float32) / np.float32(255)
        return np.ascontiguousarray(x, dtype=self.input_dtype), {
            "letterbox": p,
            "orig_shape": (h, w),
        }

    def _postprocess(
        self,
        pred: torch.Tensor,
        proto: torch.Tensor | None,
        metas: Sequence[dict],
        conf: float,
        iou: float,
        max_det: int,
    ) -> list[Prediction]:
        if self.task == "semantic":
            return self._semantic(pred, metas)
        if self.family == "darknet-yolov3":
            pred = yolov3_to_rows(pred)
        if pred.ndim != 3 or pred.shape[1] < 4 + self.num_classes:
            raise SlimsegError(
                f"model output {tuple(pred.shape)} does not match {self.num_classes} classes "
                "in its metadata"
            )
        dets = non_max_suppression(pred, self.num_classes, conf=conf, iou=iou, max_det=max_det)
        out = []
        for i, (d, meta) in enumerate(zip(dets, metas, strict=True)):
            frame = to_frame_detections(d, None if proto is None else proto[i], meta)
            classes = frame.classes
            out.append(
                Prediction(
                    boxes=frame.boxes.astype(np.float32),
                    scores=frame.scores.astype(np.float32),
                    classes=classes,
                    names=[self.names[c] for c in classes],
                    mobility=[self.mobility[c] for c in classes],
                    masks=frame.masks,
                    image_hw=frame.image_hw,
                )
            )
        return out

    def _semantic(self, logits: torch.Tensor, metas: Sequence[dict]) -> list[Prediction]:
        if logits.ndim != 4 or logits.shape[1] != self.num_classes + 1:
            raise SlimsegError(
                f"model output {tuple(logits.shape)} is not [B, {self.num_classes + 1}, H, W] "
                f"logits for the {self.num_classes} classes in its metadata"
            )
        dtype = np.uint8 if self.num_classes < 255 else np.int32
        out = []
        for i, meta in enumerate(metas):
            frame_hw = tuple(int(v) for v in meta["orig_shape"])
            class_map = logits_to_frame(logits[i], meta["letterbox"], frame_hw)
            out.append(
                Prediction(
                    boxes=np.zeros((0, 4), np.float32),
                    scores=np.zeros(0, np.float32),
                    classes=np.zeros(0, np.int64),
                    names=[],
                    mobility=[],
                    masks=None,
                    image_hw=frame_hw,
                    class_map=class_map.numpy().astype(dtype),
                    class_names=list(self.names),
                )
            )
        return out

    def predict(
        self, image_rgb: np.ndarray, conf: float = 0.25, iou: float = 0.7, max_det: int = 300
    ) -> Prediction:
        """Detect (and segment) one RGB ``uint8 [h, w, 3]`` frame; results on that frame.

        ``conf``: keep scores above it; ``iou``: class-aware NMS threshold; ``max_det``: cap.
        """
        t0 = time.perf_counter()
        x, meta = self.preprocess(image_rgb)
        t1 = time.perf_counter()
        pred, proto = self.runner(x)
        t2 = time.perf_counter()
        (result,) = self._postprocess(pred, proto, [meta], conf, iou, max_det)
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
        conf: float = 0.25,
        iou: float = 0.7,
        max_det: int = 300,
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
            pred, proto = self.runner(x)
            t2 = time.perf_counter()
            n = len(chunk)
            pred, proto = pred[:n], None if proto is None else proto[:n]
            results = self._postprocess(pred, proto, [i[1] for i in inputs], conf, iou, max_det)
            t3 = time.perf_counter()
            for r in results:
                r.timings = {
                    "preprocess": 1000 * (t1 - t0) / n,
                    "inference": 1000 * (t2 - t1) / n,
                    "postprocess": 1000 * (t3 - t2) / n,
                }
            out.extend(results)
        return out
