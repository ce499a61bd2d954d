"""End-to-end graph vs raw graph + numpy post-processing, in onnxruntime, side by side.

One 640 x 480 synthetic frame, ``slimseg predict``'s whole per-frame path (letterbox,
network, post-processing, masks on the frame) through :class:`~slimseg.deploy.predictor.
Predictor`, for both exports of the same weights at each ``--imgsz``:

- ``raw``: ``output0`` / ``output1`` + decode, NMS and mask assembly in numpy;
- ``end2end``: ``slimseg export --end2end`` (NMS, top-K and the mask product in the graph) +
  the letterbox's inverse and the masks' upsampling to the frame in numpy.

The weights are random with BatchNorm statistics of synthetic frames and class biases shifted
so that about ``--density`` of the anchor-class scores exceed 0.5 (tens of detections per
frame, as a trained model on a busy scene; a random head scores nothing or everything).

    python benchmarks/end2end_latency.py [--model yolov8n-seg] [--imgsz 320 640] [--threads 1]
        [--runs 30] [--nc 80] [--max-det K]   (K: the export's default, 100)

Prints per size: milliseconds (median) of the onnxruntime call (``run``: for ``end2end`` the
network *and* the in-graph NMS, top-K and masks, so its ratio is above 1 by construction; the
network nodes of both files are the same after onnxruntime's optimisation, ``ORT_ENABLE_ALL``
in both sessions) and the Python post-processing of each path, their totals and the ratios
end2end / raw, and the detections both kept (score > 0.25).
"""

from __future__ import annotations

import argparse
import logging
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

from slimseg.data.synth.scene import STREAM_VAL, render_image
from slimseg.deploy.end2end_graph import (
    DEFAULT_END2END_CONF,
    DEFAULT_END2END_IOU,
    DEFAULT_END2END_MAX_DET,
    End2EndSettings,
)
from slimseg.deploy.onnx_export import export_onnx
from slimseg.deploy.predictor import Predictor
from slimseg.deploy.preprocess import preprocess_frame
from slimseg.models.batchnorm_stats import batchnorm_from
from slimseg.models.registry import build_model
from slimseg.ops.nms_numpy import PREDICT_CONF


def scored_model(name: str, nc: int, imgsz: int, density: float) -> nn.Module:
    """Random ``name`` whose BatchNorm statistics come from 4 synthetic frames and whose
    class biases make about ``density`` of the anchor-class scores exceed 0.5."""
    torch.manual_seed(0)
    model = build_model(name, num_classes=nc)
    frames = [render_image(1, i, imgsz, STREAM_VAL).rgb for i in range(4)]
    batch = torch.from_numpy(
        np.concatenate([preprocess_frame(f, (imgsz, imgsz))[0] for f in frames])
    )
    batchnorm_from(model, batch)
    with torch.no_grad():
        for branch in model.detect.cls:
            branch[-1].bias.fill_(0.0)
        scores = model(batch)[0][:, 4 : 4 + nc]
        shift = torch.logit(scores.clamp(1e-6, 1 - 1e-6)).flatten().quantile(1 - density)
        for branch in model.detect.cls:
            branch[-1].bias -= shift
    return model


def timed(predictors: dict[str, Predictor], frame: np.ndarray, runs: int) -> dict[str, dict]:
    """Median ms of the network, the post-processing and the whole ``predict`` call of each
    predictor; the predictors alternate call by call, so a busy machine slows both alike."""
    keys = ("inference", "postprocess", "total")
    samples: dict[str, dict[str, list[float]]] = {t: {k: [] for k in keys} for t in predictors}
    dets = {}
    for i in range(runs + 3):
        for tag, predictor in predictors.items():
            t0 = time.perf_counter()
            pred = predictor.predict(frame, conf=PREDICT_CONF)
            total = 1000 * (time.perf_counter() - t0)
            dets[tag] = len(pred.scores)
            if i >= 3:  # warm-up
                samples[tag]["inference"].append(pred.timings["inference"])
                samples[tag]["postprocess"].append(pred.timings["postprocess"])
                samples[tag]["total"].append(total)
    return {
        tag: {**{k: statistics.median(v) for k, v in s.items()}, "detections": dets[tag]}
        for tag, s in samples.items()
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="yolov8n-seg")
    ap.add_argument("--imgsz", type=int, nargs="+", default=[320, 640])
    ap.add_argument("--nc", type=int, default=80)
    ap.add_argument("--density", type=float, default=0.0005)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument(
        "--max-det", type=int, default=DEFAULT_END2END_MAX_DET, help="the end-to-end graph's K"
    )
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    torch.set_num_threads(args.threads)
    frame = render_image(7, 0, 640, STREAM_VAL).rgb[:480]  # 640 x 480
    settings = End2EndSettings(DEFAULT_END2END_CONF, DEFAULT_END2END_IOU, args.max_det)
    print(f"{args.model}, {args.nc} classes, frame 640x480, onnxruntime CPU, {args.threads} "
          f"thread(s), median of {args.runs}, end-to-end K {args.max_det}")  # fmt: skip
    header = f"{'imgsz':>6} {'path':>8} {'run':>9} {'post':>8} {'total':>8} {'dets':>5}"
    print(header)
    with tempfile.TemporaryDirectory() as tmp:
        for side in args.imgsz:
            model = scored_model(args.model, args.nc, side, args.density)
            raw, e2e = Path(tmp) / f"raw{side}.onnx", Path(tmp) / f"e2e{side}.onnx"
            export_onnx(model, raw, (side, side))
            export_onnx(model, e2e, (side, side), end2end=settings)
            predictors = {
                tag: Predictor.from_path(path, threads=args.threads)
                for tag, path in (("raw", raw), ("end2end", e2e))
            }
            res = timed(predictors, frame, args.runs)
            for tag, r in res.items():
                print(f"{side:>6} {tag:>8} {r['inference']:>9.2f} {r['postprocess']:>8.2f} "
                      f"{r['total']:>8.2f} {r['detections']:>5}")  # fmt: skip
            a, b = res["raw"], res["end2end"]
            ratio = {k: b[k] / a[k] for k in ("inference", "postprocess", "total")}
            print(f"{side:>6} {'e2e/raw':>8} {ratio['inference']:>9.2f} "
                  f"{ratio['postprocess']:>8.2f} {ratio['total']:>8.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
