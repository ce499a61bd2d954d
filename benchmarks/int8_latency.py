"""INT8 / FP32 latency of both INT8 targets' files, every model at every size, side by side.

For each model and input size: the parity-checked FP32 export, the TensorRT-target INT8 file
(symmetric int8, convs only) and the onnxruntime-target INT8 file (uint8 activations, the
whole body), each quantized as ``slimseg export --int8 --int8-target T`` quantizes (same
calibration frames; random-init weights, so no accuracy gate), timed by onnxruntime on the
CPU round-robin in this one process (one call of each per round, ``--threads`` intra-op
threads, no spinning), so a load change hits all three alike. Prints the CPU's INT8
instruction sets and the load average beside a Markdown table of milliseconds and ratios.

Calibration frames: ``--calib`` (DATA.yaml or a folder), else a synthetic set rendered into
a temporary folder (``slimseg data synth``'s generator, seed 0).

    python benchmarks/int8_latency.py --model yolov8n-seg yolov8s-seg yolov8s-seg-gs-rep \\
        --imgsz 320 640 --runs 10
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

from slimseg.data.synth import generate
from slimseg.deploy.bench import INT8_FORMS, bench_model, machine_info
from slimseg.deploy.calibration import load_calibration_set
from slimseg.deploy.int8_placement import INT8_TARGETS
from slimseg.models.registry import build_model
from slimseg.utils.table import format_table

FORMS = ("ort_fp32", *INT8_FORMS.values())


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", nargs="+", default=["yolov8n-seg", "yolov8s-seg-gs-rep"])
    p.add_argument("--imgsz", type=int, nargs="+", default=[320, 640])
    p.add_argument("--nc", type=int, default=6)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--warmup", type=int, default=2)
    p.add_argument("--calib", default=None, help="DATA.yaml or image folder (default: synthetic)")
    p.add_argument("--calib-images", type=int, default=16)
    p.add_argument("--json", action="store_true", help="print the rows as JSON")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        source = args.calib
        if source is None:
            report = generate(Path(tmp) / "calib", 1, args.calib_images, 320, 0, progress=False)
            source = report.data_yaml
        calib = load_calibration_set(source, args.calib_images)
        rows = []
        for name in args.model:
            for size in args.imgsz:
                model = build_model(name, num_classes=args.nc)
                ms = bench_model(
                    model,
                    size,
                    args.threads,
                    args.runs,
                    args.warmup,
                    forms=("ort_fp32",),
                    calib=calib,
                    int8_targets=INT8_TARGETS,
                )
                load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
                rows.append({"model": name, "imgsz": size, "load_1min": round(load, 2), **ms})
    machine = machine_info()
    if args.json:
        print(json.dumps({"cpu": machine, "rows": rows}, indent=1))
        return
    print(f"CPU: {machine['describe']}")
    print(
        f"onnxruntime {machine['onnxruntime']}, {machine['cores']} cores, {args.threads} threads,"
        f" median of {args.runs} round-robin rounds, {len(calib.paths)} calibration frames"
    )
    headers = ["model", "imgsz", *(f"{f} ms" for f in FORMS)]
    headers += ["int8_trt/fp32", "int8_ort/fp32", "load (1 min)"]
    table = [
        [
            r["model"],
            r["imgsz"],
            *(f"{r[f]:.1f}" for f in FORMS),
            f"{r['int8_trt'] / r['ort_fp32']:.2f}",
            f"{r['int8_ort'] / r['ort_fp32']:.2f}",
            f"{r['load_1min']:.1f}",
        ]
        for r in rows
    ]
    print(format_table(headers, table, markdown=True))


if __name__ == "__main__":
    main()
