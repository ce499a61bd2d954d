"""``slimseg bench``: latency of torch (unfused, fused) and onnxruntime (FP32, FP16, INT8) in
one run."""

from __future__ import annotations

import argparse
import json

from slimseg.deploy.bench import bench_model
from slimseg.deploy.calibration import load_calibration_set
from slimseg.deploy.int8_quantize import CALIB_METHODS
from slimseg.errors import SlimsegError
from slimseg.models.registry import build_model
from slimseg.utils.table import format_table


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "bench",
        help="latency: torch unfused/fused vs onnxruntime FP32/FP16 (/INT8), with ratios",
        description="Median latency (batch 1) of each model in every deployable form, measured "
        "side by side in one process; with several models, ratios to the first are printed.",
    )
    p.add_argument("--model", nargs="+", default=["yolov8s-seg", "yolov8s-seg-gs-rep"])
    p.add_argument("--nc", type=int, default=20)
    p.add_argument("--imgsz", type=int, default=640)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--warmup", type=int, default=3)
    p.add_argument("--int8", action="store_true", help="add onnxruntime INT8 Q/DQ (needs --calib)")
    p.add_argument("--calib", default=None, help="--int8: DATA.yaml (val split) or image folder")
    p.add_argument("--calib-images", type=int, default=32, help="--int8: calibration frames")
    p.add_argument("--calib-method", default="minmax", choices=CALIB_METHODS)
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.int8 != bool(args.calib):
        raise SlimsegError("--int8 and --calib go together (INT8 needs calibration frames)")
    calib = load_calibration_set(args.calib, args.calib_images) if args.int8 else None
    results = {}
    for name in args.model:
        model = build_model(name, num_classes=args.nc)
        results[name] = bench_model(
            model,
            args.imgsz,
            args.threads,
            args.runs,
            args.warmup,
            calib=calib,
            calib_method=args.calib_method,
        )
    if args.json:
        print(json.dumps(results, indent=1))
        return 0
    forms = list(next(iter(results.values())))
    base = results[args.model[0]]
    rows = []
    for name, r in results.items():
        row: list[object] = [name]
        for form in forms:
            ratio = f" ({r[form] / base[form]:.2f})" if name != args.model[0] else ""
            row.append(f"{r[form]:.1f}{ratio}")
        row.append(f"{r['torch'] / r['ort_fp32']:.2f}")
        if calib is not None:
            row.append(f"{r['ort_int8'] / r['ort_fp32']:.2f}")
        rows.append(row)
    print(
        f"ms per image, batch 1, {args.imgsz}x{args.imgsz}, nc={args.nc}, {args.threads} "
        f"threads, median of {args.runs} (ratio to {args.model[0]} in brackets)"
    )
    ratios = ["torch/ort_fp32"] + (["ort_int8/ort_fp32"] if calib is not None else [])
    print(format_table(["model", *forms, *ratios], rows))
    if calib is not None:
        print(
            f"INT8: {len(calib.paths)} calibration frames from {args.calib} "
            f"({args.calib_method}); speed only (slimseg export --int8 gates accuracy)"
        )
    return 0
