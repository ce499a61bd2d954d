"""Cost of the finer prototype path, side by side: network (onnxruntime FP32) and mask
assembly (coefficients × prototypes, crop, upsample, back to a 640 × 480 frame) of each
base variant and its ``-hr`` twin, at each input size, measured in one process.

The networks, and then the mask assemblies, are timed round-robin (one call of each per
round) so a load change hits all of them alike. Mask assembly runs on each model's own
prototypes (an eval forward of a random input) for a fixed set of ``--dets`` person-sized
boxes with the same random coefficients for every model, so the post-processing compares
prototype sizes, not how many detections an untrained model happens to keep. Prints
milliseconds and the ``-hr``/base ratios.

    python benchmarks/mask_path.py --imgsz 320 640 --dets 10 --runs 20
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import torch

from slimseg.deploy.bench import _session_call, alternating_median_ms
from slimseg.deploy.onnx_export import export_onnx
from slimseg.detections import Detections
from slimseg.eval.complexity import measure_flops
from slimseg.eval.postprocess import to_frame_detections
from slimseg.models.registry import build_model
from slimseg.ops.letterbox import letterbox_params
from slimseg.utils.threads import torch_threads

PAIRS = (("yolov8n-seg", "yolov8n-seg-hr"), ("yolov8n-seg-gs-rep", "yolov8n-seg-gs-rep-hr"))
FRAME_HW = (480, 640)


def person_boxes(n: int, imgsz: int, seed: int = 0) -> torch.Tensor:
    """``[n, 4]`` xyxy boxes in input pixels, 12–35 % of the input high, people's aspect."""
    rng = np.random.default_rng(seed)
    h = rng.uniform(0.12, 0.35, n) * imgsz
    w = h * rng.uniform(0.3, 0.6, n)
    x = rng.uniform(0, imgsz - w)
    y = rng.uniform(imgsz * 0.125, imgsz * 0.875 - h)  # inside the letterboxed 4:3 frame
    return torch.tensor(np.stack([x, y, x + w, y + h], 1), dtype=torch.float32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--imgsz", type=int, nargs="+", default=[320, 640])
    ap.add_argument("--dets", type=int, default=10, help="detections whose masks are built")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--nc", type=int, default=6)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    names = [n for pair in PAIRS for n in pair]
    models = {n: build_model(n, num_classes=args.nc).eval() for n in names}
    rows: list[dict] = []
    with torch_threads(args.threads), tempfile.TemporaryDirectory() as tmp:
        for imgsz in args.imgsz:
            x = torch.rand(1, 3, imgsz, imgsz)
            calls = {}
            for n, m in models.items():
                path = export_onnx(m, Path(tmp) / f"{n}-{imgsz}.onnx", (imgsz, imgsz)).path
                calls[n] = _session_call(path, args.threads, x, False)
            net = alternating_median_ms(calls, args.runs, args.warmup)
            boxes = person_boxes(args.dets, imgsz)
            meta = {"letterbox": letterbox_params(*FRAME_HW, imgsz), "orig_shape": FRAME_HW}
            assemble = {}
            for n, m in models.items():
                with torch.no_grad():
                    _, proto = m.fuse()(x)
                g = torch.Generator().manual_seed(0)
                coeffs = torch.randn(args.dets, proto.shape[1], generator=g)
                scores = torch.linspace(0.9, 0.5, args.dets)
                dets = Detections(boxes, scores, torch.zeros(args.dets).long(), coeffs)
                assemble[n] = lambda d=dets, p=proto[0], mt=meta: to_frame_detections(d, p, mt)
            post = alternating_median_ms(assemble, args.runs, args.warmup)
            for n, m in models.items():
                gflops = measure_flops(m, (imgsz, imgsz))[0]
                rows.append(
                    {
                        "model": n,
                        "imgsz": imgsz,
                        "gflops": gflops,
                        "ms_net": net[n],
                        "ms_masks": post[n],
                    }
                )
    by_key = {(r["model"], r["imgsz"]): r for r in rows}
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(f"{'model':24} {'imgsz':>5} {'GFLOPs':>8} {'net ms':>8} {'masks ms':>9} {'total':>8}")
    for r in rows:
        total = r["ms_net"] + r["ms_masks"]
        print(
            f"{r['model']:24} {r['imgsz']:5d} {r['gflops']:8.3f} {r['ms_net']:8.2f} "
            f"{r['ms_masks']:9.2f} {total:8.2f}"
        )
    print(
        f"\n-hr / base ({args.dets} masks on a {FRAME_HW[1]}x{FRAME_HW[0]} frame, "
        f"{args.threads} threads, median of {args.runs})"
    )
    for base, hr in PAIRS:
        for imgsz in args.imgsz:
            b, h = by_key[(base, imgsz)], by_key[(hr, imgsz)]
            tb, th = b["ms_net"] + b["ms_masks"], h["ms_net"] + h["ms_masks"]
            print(
                f"  {hr:24} @{imgsz}: GFLOPs {h['gflops'] / b['gflops']:.3f}  "
                f"net {h['ms_net'] / b['ms_net']:.3f}  masks {h['ms_masks'] / b['ms_masks']:.3f}  "
                f"end-to-end {th / tb:.3f}"
            )


if __name__ == "__main__":
    main()
