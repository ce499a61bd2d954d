"""Every export kind in every CPU engine, side by side in one run: loads, matches, latency.

Files (one scored random model, ``end2end_latency.scored_model``: tens of detections per
frame): raw FP32 / FP16 / ``--dynamic``, end-to-end FP32 / FP16 / dynamic, INT8 Q/DQ for the
``tensorrt`` and the ``onnxruntime`` target. Engines: onnxruntime (CPU provider), OpenVINO at
f32 (what ``--backend openvino`` sets), OpenVINO at this CPU's default precision (bf16 on a CPU
with AVX512_BF16 / AMX, f16 on ARM, f32 otherwise; run as ``openvino:<default>``), and OpenCV
DNN (``cv2.dnn.readNetFromONNX``).

Per file x engine: ``loads`` (or the first line of the error), ``match``: the fraction of
onnxruntime's instances on the same file the engine keeps on held-out 640 x 480 frames (same
class, box and mask IoU >= 0.9, |score diff| <= 0.02; score > 0.25), for raw files also the
worst element in multiples of the export's FP32 limits (``limit x``); ``vs FP32``: the same
against onnxruntime on the raw FP32 file (what INT8 and FP16 keep of FP32); ``ratio``: the median
time of the whole per-frame path (``Predictor.predict``: letterbox, network,
post-processing, masks on the frame) divided by onnxruntime's on the raw FP32 file, the two
timed alternately in the same rounds; ``net``: the same ratio of the network call alone.
INT8 files also run in onnxruntime with its graph optimisations off (``ort:qdq-float``: the
Q/DQ computed as written, in float), which says how far onnxruntime's own integer kernels are
from the file's arithmetic. Then the per-frame masking chain (``slimseg.Masker.step``, fusion
mode) with each engine on the raw FP32, end-to-end FP32 and both INT8 files, ratios to
onnxruntime on the raw FP32 file.

    python benchmarks/engines.py [--model yolov8n-seg] [--imgsz 320] [--threads 1] [--runs 20]
    python benchmarks/engines.py --onnx ../shared/models/demo-intel/yolov8n-seg-gs-rep.onnx

``--onnx``: a trained static FP32 export instead of the random model (every kind derived from
it; the dynamic ones from the weights recovered from it, ``onnx_weights.py``); the frames are
the synthetic scenes the demo trains on, so a trained demo model has real detections and a
meaningful INT8.
"""

from __future__ import annotations

import argparse
import json
import logging
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import onnx
import torch
from end2end_latency import scored_model
from onnx_weights import model_from_onnx

from slimseg.data.synth.scene import STREAM_VAL, render_image
from slimseg.deploy.calibration import load_calibration_set
from slimseg.deploy.end2end_graph import (
    DEFAULT_END2END_CONF,
    DEFAULT_END2END_IOU,
    DEFAULT_END2END_MAX_DET,
    End2EndSettings,
    append_end2end,
)
from slimseg.deploy.end2end_parity import match_predictions
from slimseg.deploy.int8_quantize import quantize_onnx
from slimseg.deploy.masker import Masker
from slimseg.deploy.metadata import with_end2end
from slimseg.deploy.onnx_export import export_onnx, to_fp16
from slimseg.deploy.onnx_io import publish, stage, staging_dir
from slimseg.deploy.ort_session import cpu_session
from slimseg.deploy.ov_checks import precision_excess
from slimseg.deploy.predictor import Predictor
from slimseg.deploy.runners import OnnxRunner
from slimseg.detections import Prediction
from slimseg.ops.nms_numpy import PREDICT_CONF

QDQ_FLOAT = "ort:qdq-float"  # INT8 files only: onnxruntime's Q/DQ as written, in float
KINDS = ("raw32", "raw16", "rawdyn", "e2e32", "e2e16", "e2edyn", "int8_trt", "int8_ort")


class CvDnnSession:
    """OpenCV DNN behind :class:`~slimseg.deploy.runners.GraphSession` (ports read from
    onnxruntime's session of the same file)."""

    def __init__(self, path: Path, threads: int) -> None:
        cv2.setNumThreads(threads)
        self.net = cv2.dnn.readNetFromONNX(str(path))
        self.ports = cpu_session(path, 1)

    def get_inputs(self) -> list:
        return self.ports.get_inputs()

    def get_outputs(self) -> list:
        return self.ports.get_outputs()

    def run(self, output_names: list[str], input_feed: dict[str, np.ndarray]) -> list:
        ((name, x),) = input_feed.items()
        self.net.setInput(x, name)
        return list(self.net.forward(output_names))


def qdq_float_session(path: Path, threads: int) -> Any:
    """onnxruntime with no graph optimisation: an INT8 file's Q/DQ computed as written, in
    float (the ONNX operators' own arithmetic; its default fuses them into integer kernels)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    opts.intra_op_num_threads = threads
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def _publish(proto: onnx.ModelProto, meta: dict, out: Path) -> Path:
    with staging_dir(out) as tmp:
        publish(stage(proto, meta, tmp, out.name), meta, out)
    return out


def _sidecar(path: Path) -> dict:
    return json.loads(path.with_suffix(".json").read_text())


def _end2end(raw: Path, out: Path, nc: int, settings: End2EndSettings) -> Path:
    meta = _sidecar(raw)
    batch, anchors = "batch", None
    if not meta["dynamic_shapes"]:
        h, w = meta["imgsz"]
        batch, anchors = 1, sum((h // s) * (w // s) for s in meta["strides"])
    proto = append_end2end(
        onnx.load(str(raw)), nc, int(meta["num_masks"]), settings, batch, anchors
    )
    return _publish(proto, with_end2end(meta, settings.as_dict()), out)


def make_files(model: torch.nn.Module | Path, side: int, nc: int, root: Path) -> dict[str, Path]:
    """Every export kind of ``model`` (weights, or a trained static FP32 ``.onnx``: its
    dynamic kinds from the weights :func:`onnx_weights.model_from_onnx` recovers) at ``side``
    px (FP16 without the FP16 gate, which a random head need not pass; INT8 calibrated on 8
    synthetic frames, min-max)."""
    files = {"raw32": root / "raw32.onnx", "rawdyn": root / "rawdyn.onnx"}
    if isinstance(model, Path):
        meta = _sidecar(model)
        _publish(onnx.load(str(model)), meta, files["raw32"])
        fused, _ = model_from_onnx(model)
        export_onnx(fused, files["rawdyn"], (side, side), meta["names"], meta["mobility"],
                    dynamic=True)  # fmt: skip
    else:
        export_onnx(model, files["raw32"], (side, side))
        export_onnx(model, files["rawdyn"], (side, side), dynamic=True)
    meta = {**_sidecar(files["raw32"]), "precision": "fp16"}
    files["raw16"] = _publish(to_fp16(onnx.load(str(files["raw32"]))), meta, root / "raw16.onnx")
    settings = End2EndSettings(DEFAULT_END2END_CONF, DEFAULT_END2END_IOU, DEFAULT_END2END_MAX_DET)
    for key, raw in (("e2e32", "raw32"), ("e2e16", "raw16"), ("e2edyn", "rawdyn")):
        if raw in files:
            files[key] = _end2end(files[raw], root / f"{key}.onnx", nc, settings)
    calib = root / "calib"
    calib.mkdir()
    for i in range(8):
        cv2.imwrite(
            str(calib / f"{i}.png"), render_image(3, i, side * 2, STREAM_VAL).rgb[:, :, ::-1]
        )
    frames = load_calibration_set(calib, 8)
    for key, target in (("int8_trt", "tensorrt"), ("int8_ort", "onnxruntime")):
        q = root / f"{key}-q.onnx"
        quantize_onnx(files["raw32"], q, frames, (side, side), "yolov8", "minmax", False, None,
                      target)  # fmt: skip
        meta = {**_sidecar(files["raw32"]), "precision": "int8", "int8": {"target": target}}
        files[key] = _publish(onnx.load(str(q)), meta, root / f"{key}.onnx")
    return files


def open_engine(path: Path, engine: str, threads: int) -> Predictor:
    if engine in ("opencv", QDQ_FLOAT):
        ort = Predictor.from_path(path, threads=threads)
        session = (
            CvDnnSession(path, threads) if engine == "opencv" else qdq_float_session(path, threads)
        )
        runner = OnnxRunner(session, str(path))
        return Predictor(runner, ort.metadata, ort.imgsz, engine, path, threads)
    return Predictor.from_path(path, backend=engine, threads=threads)


def timed(
    fns: dict[str, Any], runs: int, warmup: int = 3
) -> tuple[dict[str, float], dict[str, float]]:
    """Median ms of each callable, called round-robin (a busy machine slows all alike), and
    the median of the ``timings["inference"]`` of what it returns (a Prediction), if any."""
    samples: dict[str, list[float]] = {k: [] for k in fns}
    network: dict[str, list[float]] = {k: [] for k in fns}
    for i in range(runs + warmup):
        for key, fn in fns.items():
            t0 = time.perf_counter()
            out = fn(i)
            if i >= warmup:
                samples[key].append(1000 * (time.perf_counter() - t0))
                if isinstance(out, Prediction):
                    network[key].append(out.timings["inference"])
    medians = {k: statistics.median(v) for k, v in samples.items()}
    return medians, {k: statistics.median(v) for k, v in network.items() if v}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="yolov8n-seg")
    ap.add_argument("--onnx", type=Path, default=None, help="a trained static FP32 export")
    ap.add_argument("--imgsz", type=int, default=320)
    ap.add_argument("--nc", type=int, default=80)
    ap.add_argument("--density", type=float, default=0.0005)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--frames", type=int, default=4, help="held-out frames for the match")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    torch.set_num_threads(args.threads)
    import openvino as ov

    default = ov.Core().get_property("CPU", "INFERENCE_PRECISION_HINT").get_type_name()
    engines = ["onnxruntime", "openvino"] + ([f"openvino:{default}"] if default != "f32" else [])
    engines.append("opencv")
    frames = [render_image(7, i, 640, STREAM_VAL).rgb[:480] for i in range(args.frames)]
    with tempfile.TemporaryDirectory() as tmp:
        if args.onnx is not None:
            meta = _sidecar(args.onnx)
            args.imgsz, args.nc, args.model = meta["imgsz"][0], len(meta["names"]), args.onnx.name
            files = make_files(args.onnx, args.imgsz, args.nc, Path(tmp))
        else:
            model = scored_model(args.model, args.nc, args.imgsz, args.density)
            files = make_files(model, args.imgsz, args.nc, Path(tmp))
        print(
            f"{args.model}, {args.nc} classes, {args.imgsz} px, frames 640x480, {args.threads} "
            f"thread(s), median of {args.runs}; OpenVINO {ov.__version__.split('-')[0]}, CPU "
            f"default precision {default}; ratio: time / onnxruntime raw FP32's, same rounds"
        )
        base = open_engine(files["raw32"], "onnxruntime", args.threads)
        print(f"{'file':>9} {'engine':>14} {'loads':>6} {'match':>7} {'vs FP32':>7} "
              f"{'limit x':>9} {'ms':>7} {'ratio':>6} {'net':>6}")  # fmt: skip
        opened: dict[tuple[str, str], Predictor] = {}
        for kind in (k for k in KINDS if k in files):
            ref = open_engine(files[kind], "onnxruntime", args.threads)
            ref_preds = [ref.predict(f, conf=PREDICT_CONF) for f in frames]
            fp32_preds = [base.predict(f, conf=PREDICT_CONF) for f in frames]
            row: dict[str, Predictor] = {}
            cells: dict[str, tuple[str, str, str]] = {}  # engine -> (match, FP32 match, limit x)
            for engine in engines + ([QDQ_FLOAT] if kind.startswith("int8") else []):
                try:
                    row[engine] = open_engine(files[kind], engine, args.threads)
                    preds = [row[engine].predict(f, conf=PREDICT_CONF) for f in frames]
                except Exception as exc:  # an engine's own error: the table says which
                    row.pop(engine, None)
                    msg = (str(exc).splitlines() or [type(exc).__name__])[0][:60]
                    print(f"{kind:>9} {engine:>14} {'no':>6}  {msg}")
                    continue
                m = match_predictions(ref_preds, preds)
                limit = ""
                if not ref.end2end and engine != "onnxruntime":
                    x = ref.preprocess(frames[0])[0]
                    nc = len(ref.names)
                    excess = precision_excess(ref.runner.raw(x), row[engine].runner.raw(x), nc)
                    limit = f"{excess[0]:.3g}"
                f = match_predictions(fp32_preds, preds)
                cells[engine] = (f"{m['matched']}/{m['detections']}",
                                 f"{f['matched']}/{f['detections']}", limit)  # fmt: skip
            fns = {"base": lambda i: base.predict(frames[i % len(frames)], conf=PREDICT_CONF)}
            for engine, p in row.items():
                fns[engine] = lambda i, p=p: p.predict(frames[i % len(frames)], conf=PREDICT_CONF)
            ms, net = timed(fns, args.runs)
            for engine, p in row.items():
                opened[(kind, engine)] = p
                match, vs32, limit = cells[engine]
                print(f"{kind:>9} {engine:>14} {'yes':>6} {match:>7} {vs32:>7} {limit:>9} "
                      f"{ms[engine]:>7.2f} {ms[engine] / ms['base']:>6.2f} "
                      f"{net[engine] / net['base']:>6.2f}")  # fmt: skip
        print(
            "\nper-frame masking chain (slimseg.Masker.step, fusion), ratio to onnxruntime raw FP32"
        )
        chain = [(k, e) for e in engines for k in ("raw32", "e2e32", "int8_ort", "int8_trt")]
        maskers = {
            f"{k} {e}": Masker.from_predictor(opened[(k, e)]) for k, e in chain if (k, e) in opened
        }
        steps = {t: lambda i, m=m: m.step(frames[i % len(frames)]) for t, m in maskers.items()}
        ms, _ = timed(steps, args.runs)
        ref_ms = ms["raw32 onnxruntime"]
        for tag, v in ms.items():
            print(f"{tag:>24} {v:>8.2f} ms {v / ref_ms:>6.2f}")


if __name__ == "__main__":
    main()
