"""``slimseg export``: fused FP32/FP16 ONNX with metadata, verified against torch."""

from __future__ import annotations

import argparse
from pathlib import Path

from slimseg.deploy.checkpoint import load_weights
from slimseg.deploy.onnx_export import export_onnx
from slimseg.models.registry import build_model


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export",
        help="fused ONNX (FP32/FP16) with metadata and a verified parity check",
        description="EMA weights -> fuse -> ONNX -> checker -> onnxslim -> (FP16) -> metadata "
        "-> onnxruntime vs torch parity on two inputs. The file (and NAME.json sidecar) appears "
        "at --out only if parity holds; otherwise the command fails and leaves nothing.",
    )
    p.add_argument("--weights", required=True, help="weights .pt/.ckpt, or a model name")
    p.add_argument("--imgsz", type=int, nargs="+", default=[640], help="H [W], multiples of 32")
    p.add_argument("--nc", type=int, default=None, help="classes, when --weights is a name")
    p.add_argument("--half", action="store_true", help="FP16 weights, compute, input, outputs")
    p.add_argument("--dynamic", action="store_true", help="dynamic batch, height and width")
    p.add_argument("--opset", type=int, default=18)
    p.add_argument("--no-simplify", action="store_true", help="skip onnxslim")
    p.add_argument("--out", default=None, help="output .onnx (default export/<model>.onnx)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    source = Path(args.weights)
    if source.suffix in (".pt", ".ckpt"):
        model, info = load_weights(source)
        names, mobility = info.names, info.mobility
    else:
        model = build_model(args.weights, num_classes=args.nc).eval()
        names, mobility = [], []
    imgsz = (args.imgsz[0], args.imgsz[-1])
    suffix = "-fp16" if args.half else ""
    out = Path(args.out) if args.out else Path("export") / f"{model.spec.name}{suffix}.onnx"
    report = export_onnx(
        model,
        out,
        imgsz,
        names,
        mobility,
        half=args.half,
        dynamic=args.dynamic,
        opset=args.opset,
        simplify=not args.no_simplify,
    )
    print(f"wrote {report.path} ({report.precision}, opset {report.opset}, {report.nodes} nodes)")
    print(f"  metadata sidecar {report.sidecar}")
    print(f"  ops: {', '.join(report.ops)}")
    print("  parity vs fused torch: " + ", ".join(f"{k} {v:.3g}" for k, v in report.parity.items()))
    return 0
