"""``slimseg bench``: latency of torch (unfused, fused) and onnxruntime (FP32, FP16, and the
INT8 file of each target) in one run, with the CPU's INT8 instruction sets beside it."""

from __future__ import annotations

import argparse
import json

from slimseg.cli.arg_types import count, multiple_of, threads
from slimseg.cli.commands import COMMAND_HELP
from slimseg.deploy.bench import INT8_FORMS, bench_model, machine_info
from slimseg.deploy.calibration import load_calibration_set
from slimseg.deploy.int8_placement import INT8_TARGETS
from slimseg.deploy.int8_quantize import CALIB_METHODS
from slimseg.errors import SlimsegError
from slimseg.models.registry import build_model
from slimseg.utils.table import format_table
from slimseg.utils.threads import available_cpus


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "bench",
        help=COMMAND_HELP["bench"],
        description="Median latency (batch 1) of each model in every deployable form, measured "
        "side by side in one process (onnxruntime forms round-robin); with several models, "
        "ratios to the first are printed. --int8 adds the INT8 file of each --int8-target: "
        "int8_trt (the TensorRT file, run here by onnxruntime) and int8_ort (the onnxruntime "
        "file). The CPU's INT8 instruction sets (AVX2, AVX-512 VNNI, AVX-VNNI, AMX, ARM dot "
        "product) and the load average are printed with the figures (--json: the 'cpu' key).",
    )
    p.add_argument("--model", nargs="+", default=["yolov8s-seg", "yolov8s-seg-gs-rep"])
    p.add_argument("--nc", type=count(1), default=20)
    p.add_argument("--imgsz", type=multiple_of(), default=640)
    p.add_argument("--threads", type=threads(), default=min(2, available_cpus()))
    p.add_argument("--runs", type=count(1), default=10)
    p.add_argument("--warmup", type=count(0), default=3)
    p.add_argument("--int8", action="store_true", help="add onnxruntime INT8 Q/DQ (needs --calib)")
    p.add_argument("--calib", default=None, help="--int8: DATA.yaml (val split) or image folder")
    p.add_argument("--calib-images", type=count(1), default=32, help="--int8: calibration frames")
    p.add_argument("--calib-method", default="minmax", choices=CALIB_METHODS)
    p.add_argument(
        "--int8-target",
        nargs="+",
        default=list(INT8_TARGETS),
        choices=INT8_TARGETS,
        help="--int8: which targets' files to time (default: both)",
    )
    p.add_argument(
        "--backend",
        default="onnxruntime",
        choices=("onnxruntime", "openvino"),
        help="openvino: each ONNX form also in OpenVINO at f32 (ov_*), in the same rounds",
    )
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.int8 != bool(args.calib):
        raise SlimsegError("--int8 and --calib go together (INT8 needs calibration frames)")
    calib = load_calibration_set(args.calib, args.calib_images) if args.int8 else None
    targets = tuple(dict.fromkeys(args.int8_target))
    results: dict[str, dict[str, float]] = {}
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
            int8_targets=targets,
            openvino=args.backend == "openvino",
        )
    machine = machine_info()
    if args.json:
        print(json.dumps({**results, "cpu": machine}, indent=1))
        return 0
    forms = list(next(iter(results.values())))
    int8_forms = [INT8_FORMS[t] for t in targets] if calib is not None else []
    int8_forms += [f for f in forms if f.startswith("ov_")]
    base = results[args.model[0]]
    rows = []
    for name, r in results.items():
        row: list[object] = [name]
        for form in forms:
            ratio = f" ({r[form] / base[form]:.2f})" if name != args.model[0] else ""
            row.append(f"{r[form]:.1f}{ratio}")
        row.append(f"{r['torch'] / r['ort_fp32']:.2f}")
        row += [f"{r[f] / r['ort_fp32']:.2f}" for f in int8_forms]
        rows.append(row)
    print(
        f"ms per image, batch 1, {args.imgsz}x{args.imgsz}, nc={args.nc}, {args.threads} "
        f"threads, median of {args.runs} (ratio to {args.model[0]} in brackets)"
    )
    ratios = ["torch/ort_fp32"] + [f"{f}/ort_fp32" for f in int8_forms]
    print(format_table(["model", *forms, *ratios], rows))
    print(f"CPU: {machine['describe']}")
    print(
        f"onnxruntime {machine['onnxruntime']}, {machine['cores']} cores, load average "
        f"{machine['load_average'][0]:.1f} when done (ratios come from one process, round-robin)"
    )
    if calib is not None:
        names = {
            "tensorrt": "int8_trt = TensorRT file",
            "onnxruntime": "int8_ort = onnxruntime file",
        }
        print(
            f"INT8: {len(calib.paths)} calibration frames from {args.calib} "
            f"({args.calib_method}); {'; '.join(names[t] for t in targets)}; speed only "
            "(slimseg export --int8 gates accuracy)"
        )
    return 0
