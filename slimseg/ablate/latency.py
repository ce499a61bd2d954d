"""Latency of a sweep run at one or more input sizes: the fused FP32 ONNX export in
onnxruntime, and (``masks: true``) the post-processing a user's frame goes through.

Per size ``S`` the best weights are exported with a static ``S × S`` input
(``model.onnx`` at the training imgsz, ``model-S.onnx`` otherwise) and loaded in a
:class:`~slimseg.deploy.predictor.Predictor`; one val frame (``uint8 [h, w, 3]`` RGB) is
letterboxed to ``S`` once. Columns (median of ``runs`` calls after ``warmup``, batch 1,
``threads`` intra-op threads for onnxruntime and torch alike):

- ``ms_net@S``: the network (onnxruntime session) on that input;
- ``ms_post@S`` (with ``masks``): NMS at ``conf`` plus mask assembly — coefficients ×
  prototypes, crop to the box, upsample to the frame (:mod:`slimseg.ops.masks`), exactly
  :meth:`Predictor.predict`'s post-processing step;
- ``dets@S`` (with ``masks``): detections kept on that frame (the post-processing cost
  grows with it; an undertrained model may keep none).
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
from torch import nn

from slimseg.deploy.bench import median_ms
from slimseg.deploy.onnx_export import export_onnx
from slimseg.deploy.predictor import Predictor
from slimseg.models.checkpoint import WeightsInfo
from slimseg.ops.nms import PREDICT_CONF
from slimseg.utils.threads import torch_threads


@dataclass(frozen=True)
class BenchOptions:
    """``imgsz``: the sizes to time (``None``: the sweep's training imgsz; one int or a
    list in the YAML); ``masks``: also time NMS + mask assembly on a val frame at ``conf``."""

    runs: int = 20
    warmup: int = 3
    threads: int = 2
    imgsz: tuple[int, ...] | None = None
    masks: bool = False
    conf: float = PREDICT_CONF

    def sizes(self, train_imgsz: int) -> tuple[int, ...]:
        """The sizes timed, first one the headline ``latency_ms``."""
        return self.imgsz if self.imgsz is not None else (train_imgsz,)


def latency_columns(sizes: Sequence[int], masks: bool) -> list[str]:
    """Row columns :func:`bench_latency` fills, in order."""
    per = ("ms_net", "ms_post", "dets") if masks else ("ms_net",)
    return [f"{p}@{s}" for s in sizes for p in per]


def onnx_name(size: int, train_imgsz: int) -> str:
    """File of the export timed at ``size`` inside the run folder."""
    return "model.onnx" if size == train_imgsz else f"model-{size}.onnx"


def bench_latency(
    model: nn.Module,
    info: WeightsInfo,
    run_dir: Path,
    train_imgsz: int,
    opts: BenchOptions,
    frame: np.ndarray,
) -> dict[str, float]:
    """:func:`latency_columns` of ``model`` (unfused weights; fused by the export) for
    every size of ``opts``; ``frame``: ``uint8 [h, w, 3]`` RGB, a val image."""
    out: dict[str, float] = {}
    for size in opts.sizes(train_imgsz):
        path = Path(run_dir) / onnx_name(size, train_imgsz)
        export_onnx(model, path, (size, size), names=info.names, mobility=info.mobility)
        predictor = Predictor.from_path(path, threads=opts.threads)
        if opts.masks:
            net, post, dets = _end_to_end(predictor, frame, opts)
            out |= {f"ms_net@{size}": net, f"ms_post@{size}": post, f"dets@{size}": dets}
        else:
            x, _ = predictor.preprocess(frame)
            out[f"ms_net@{size}"] = median_ms(partial(predictor.runner, x), opts.runs, opts.warmup)
    return out


def _end_to_end(
    predictor: Predictor, frame: np.ndarray, opts: BenchOptions
) -> tuple[float, float, float]:
    """Median network and post-processing ms of :meth:`Predictor.predict`, detections kept."""
    net: list[float] = []
    post: list[float] = []
    dets = 0
    with torch_threads(opts.threads):
        for i in range(opts.warmup + opts.runs):
            result = predictor.predict(frame, conf=opts.conf)
            if i >= opts.warmup:
                net.append(result.timings["inference"])
                post.append(result.timings["postprocess"])
            dets = len(result.boxes)
    return statistics.median(net), statistics.median(post), float(dets)
