"""Steps of ``benchmarks/gpu_check.sh`` that need Python: one JSON line each on stdout.

    python benchmarks/gpu_check.py train --data D.yaml --out RUN [--device cuda] ...
    python benchmarks/gpu_check.py ort MODEL.onnx [--device cuda]
    python benchmarks/gpu_check.py trt-build MODEL.onnx ENGINE [--int8]
    python benchmarks/gpu_check.py trt-latency ENGINE

Every step exits non-zero with a one-line reason when it cannot run (no CUDA device, no
onnxruntime CUDA provider, no ``tensorrt`` package): the shell script reports it as FAILED.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import lightning as L
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from reference_impl import StepClock

from slimseg.engine.config import TrainConfig
from slimseg.engine.train import train


class _Clock(L.Callback):
    def __init__(self, clock: StepClock) -> None:
        self.clock = clock

    def on_train_batch_end(self, trainer: L.Trainer, *args: object) -> None:
        if trainer.strategy.root_device.type == "cuda":
            torch.cuda.synchronize()
        self.clock.tick()


def fail(message: str) -> None:
    print(f"gpu_check: FAILED: {message}", file=sys.stderr)
    sys.exit(1)


def cmd_train(args: argparse.Namespace) -> None:
    gpu = args.device == "cuda"
    if gpu and not torch.cuda.is_available():
        fail("torch sees no CUDA device")
    cfg = TrainConfig(
        epochs=args.epochs,
        batch=args.batch,
        imgsz=args.imgsz,
        workers=args.workers,
        close_mosaic=0,
        val_every=args.epochs,
    )
    clock = StepClock(args.batch, warmup=min(3, max(len_hint(args) - 2, 0)))
    if gpu:
        torch.cuda.reset_peak_memory_stats()
    start = time.perf_counter()
    module, out = train(
        args.model,
        args.data,
        cfg,
        Path(args.out),
        accelerator="gpu" if gpu else "cpu",
        devices=1,
        progress=False,
        callbacks=[_Clock(clock)],
        precision="16-mixed" if gpu else "32-true",
    )
    record = {
        "step": "train",
        "model": args.model,
        "imgsz": args.imgsz,
        "batch": args.batch,
        "epochs": args.epochs,
        "precision": module.trainer.precision,
        "images_per_s": round(clock.images_per_s(), 2),
        "wall_s": round(time.perf_counter() - start, 1),
        "run": str(out),
        "peak_memory_gib": round(torch.cuda.max_memory_allocated() / 2**30, 2) if gpu else None,
        "mask_map50_95": (module.last_metrics.get("mask") or {}).get("map50_95"),
    }
    print(json.dumps(record))


def len_hint(args: argparse.Namespace) -> int:
    """Batches per epoch of the synthetic train split (for the clock's warm-up)."""
    return max(args.train_images // args.batch, 1) * args.epochs


def _latency(run_once: object, runs: int, warmup: int) -> dict:
    for _ in range(warmup):
        run_once()
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        run_once()
        times.append(1000 * (time.perf_counter() - t0))
    return {"median_ms": round(float(np.median(times)), 3), "runs": runs}


def cmd_ort(args: argparse.Namespace) -> None:
    import onnxruntime as ort

    wanted = "CUDAExecutionProvider" if args.device == "cuda" else "CPUExecutionProvider"
    if wanted not in ort.get_available_providers():
        fail(f"onnxruntime has no {wanted} (onnxruntime-gpu not installed?)")
    sess = ort.InferenceSession(args.onnx, providers=[wanted])
    inp = sess.get_inputs()[0]
    shape = [d if isinstance(d, int) else 1 for d in inp.shape]
    x = np.random.default_rng(0).random(shape, np.float32)
    if "float16" in inp.type:
        x = x.astype(np.float16)
    result = _latency(lambda: sess.run(None, {inp.name: x}), args.runs, args.warmup)
    print(json.dumps({"step": "ort", "onnx": args.onnx, "provider": wanted, **result}))


def _tensorrt():
    try:
        import tensorrt as trt
    except ImportError:
        fail("the tensorrt Python package is not installed (and trtexec was not found)")
    return trt


def cmd_trt_build(args: argparse.Namespace) -> None:
    trt = _tensorrt()
    logger = trt.Logger(trt.Logger.WARNING)
    builder = trt.Builder(logger)
    network = builder.create_network(0)
    parser = trt.OnnxParser(network, logger)
    if not parser.parse(Path(args.onnx).read_bytes()):
        errors = "; ".join(str(parser.get_error(i)) for i in range(parser.num_errors))
        fail(f"{args.onnx}: TensorRT cannot parse it ({errors})")
    config = builder.create_builder_config()
    config.set_flag(trt.BuilderFlag.FP16)
    if args.int8:
        config.set_flag(trt.BuilderFlag.INT8)  # explicit quantization: the QDQ nodes decide
    engine = builder.build_serialized_network(network, config)
    if engine is None:
        fail(f"{args.onnx}: TensorRT engine build failed")
    Path(args.engine).write_bytes(bytes(engine))
    print(json.dumps({"step": "trt-build", "engine": args.engine, "int8": args.int8}))


def cmd_trt_latency(args: argparse.Namespace) -> None:
    trt = _tensorrt()
    if not torch.cuda.is_available():
        fail("torch sees no CUDA device")
    runtime = trt.Runtime(trt.Logger(trt.Logger.WARNING))
    engine = runtime.deserialize_cuda_engine(Path(args.engine).read_bytes())
    if engine is None:
        fail(f"{args.engine}: cannot deserialize the engine")
    context = engine.create_execution_context()
    buffers = []
    for i in range(engine.num_io_tensors):
        name = engine.get_tensor_name(i)
        shape = [d if d > 0 else 1 for d in engine.get_tensor_shape(name)]
        if engine.get_tensor_mode(name) == trt.TensorIOMode.INPUT:
            context.set_input_shape(name, shape)
        dtype = torch.float16 if engine.get_tensor_dtype(name) == trt.float16 else torch.float32
        buf = torch.rand(shape, device="cuda").to(dtype)
        buffers.append(buf)
        context.set_tensor_address(name, buf.data_ptr())
    stream = torch.cuda.Stream()

    def run_once() -> None:
        context.execute_async_v3(stream.cuda_stream)
        stream.synchronize()

    result = _latency(run_once, args.runs, args.warmup)
    print(json.dumps({"step": "trt-latency", "engine": args.engine, **result}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("train")
    t.add_argument("--data", required=True)
    t.add_argument("--out", required=True)
    t.add_argument("--model", default="yolov8s-seg-gs-rep")
    t.add_argument("--imgsz", type=int, default=640)
    t.add_argument("--epochs", type=int, default=2)
    t.add_argument("--batch", type=int, default=16)
    t.add_argument("--workers", type=int, default=8)
    t.add_argument("--train-images", type=int, default=512)
    t.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    o = sub.add_parser("ort")
    o.add_argument("onnx")
    o.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    b = sub.add_parser("trt-build")
    b.add_argument("onnx")
    b.add_argument("engine")
    b.add_argument("--int8", action="store_true")
    lat = sub.add_parser("trt-latency")
    lat.add_argument("engine")
    for p in (o, lat):
        p.add_argument("--runs", type=int, default=200)
        p.add_argument("--warmup", type=int, default=20)
    args = ap.parse_args()
    {"train": cmd_train, "ort": cmd_ort, "trt-build": cmd_trt_build}.get(args.cmd, cmd_trt_latency)(
        args
    )


if __name__ == "__main__":
    main()
