"""``slimseg export``: fused FP32/FP16 ONNX with metadata, verified against torch; INT8 Q/DQ
ONNX calibrated on real frames and gated on COCO mAP."""

from __future__ import annotations

import argparse
from pathlib import Path

from slimseg.cli.arg_types import count, image_side, number
from slimseg.cli.commands import COMMAND_HELP
from slimseg.deploy.end2end_graph import (
    DEFAULT_END2END_CONF,
    DEFAULT_END2END_IOU,
    DEFAULT_END2END_MAX_DET,
    End2EndSettings,
)
from slimseg.deploy.int8_export import DEFAULT_MAX_DROP, export_int8
from slimseg.deploy.int8_placement import DEFAULT_INT8_TARGET, INT8_TARGETS
from slimseg.deploy.int8_quantize import CALIB_METHODS
from slimseg.deploy.onnx_export import export_onnx
from slimseg.deploy.onnx_io import sidecar_path
from slimseg.errors import SlimsegError
from slimseg.models.checkpoint import load_weights
from slimseg.models.registry import build_model
from slimseg.utils.outputs import refuse_inputs

MAX_EXPORT_SIDE = 4096  # a 4096 x 4096 trace already holds GBs of activations
END2END_MASK_BYTES = 1 << 30  # the most one image's end-to-end masks [K, H/4, W/4] may take


def check_end2end_size(max_det: int, imgsz: list[int]) -> None:
    """``SlimsegError`` before anything is built when the end-to-end graph's masks (``max_det``
    rows of float32 at prototype resolution, padded rows included) would take more than
    :data:`END2END_MASK_BYTES` for one ``imgsz`` image (H, or H W)."""
    stride = End2EndSettings.proto_stride
    h, w = imgsz[0], imgsz[-1]
    need = max_det * -(-h // stride) * -(-w // stride) * 4
    if need > END2END_MASK_BYTES:
        most = END2END_MASK_BYTES // (-(-h // stride) * -(-w // stride) * 4)
        raise SlimsegError(
            f"--end2end --max-det {max_det} --imgsz {h} {w}: the masks of one image would take "
            f"{need / 2**30:.3g} GiB (limit {END2END_MASK_BYTES / 2**30:g} GiB); give --max-det "
            f"{most} or less, or a smaller --imgsz"
        )


def add_parser(sub: argparse._SubParsersAction) -> None:
    from slimseg.calibrate.run import DEFAULT_BUDGET_S

    p = sub.add_parser(
        "export",
        help=COMMAND_HELP["export"],
        description="EMA weights -> fuse -> ONNX -> checker -> onnxslim -> (FP16) -> metadata "
        "-> onnxruntime vs torch parity on two inputs (with --dynamic also batch 2 and a second "
        "size). --int8: that FP32 graph -> calibration on real frames -> Q/DQ for the "
        "--int8-target (tensorrt: symmetric int8, convs only, for TensorRT engines; "
        "onnxruntime: uint8 activations, the whole body, for onnxruntime on a CPU) -> box "
        "and mask mAP50-95 of FP32 and INT8 on the val split; refused when either drops more "
        "than --int8-max-drop points. The file (and NAME.json sidecar) appears at --out only if "
        "the checks hold; otherwise the command fails and leaves nothing. --end2end: NMS and "
        "mask assembly inside the graph (standard ONNX operators; docs/end2end.md), gated on "
        "slimseg predict's instances on synthetic frames.",
    )
    p.add_argument("--weights", required=True, help="weights .pt/.ckpt, or a model name")
    p.add_argument(
        "--imgsz",
        type=image_side(MAX_EXPORT_SIDE),
        nargs="+",
        default=[640],
        help=f"H [W], multiples of 32 up to {MAX_EXPORT_SIDE}",
    )
    p.add_argument("--nc", type=count(1), default=None, help="classes, when --weights is a name")
    p.add_argument("--half", action="store_true", help="FP16 weights, compute, input, outputs")
    p.add_argument("--dynamic", action="store_true", help="dynamic batch, height and width")
    p.add_argument("--opset", type=count(1), default=18)
    p.add_argument("--no-simplify", action="store_true", help="skip onnxslim")
    p.add_argument(
        "--end2end",
        action="store_true",
        help="decode, class-aware NMS, top --max-det and masks inside the graph (yolov8)",
    )
    p.add_argument(
        "--conf",
        type=number(0, 1, open_high=True),
        default=None,
        help=f"--end2end: keep scores above it (default {DEFAULT_END2END_CONF})",
    )
    p.add_argument(
        "--iou",
        type=number(0, 1, open_low=True),
        default=None,
        help=f"--end2end: NMS IoU threshold (default {DEFAULT_END2END_IOU})",
    )
    p.add_argument(
        "--max-det",
        type=count(1),
        default=None,
        help=f"--end2end: rows per image (default {DEFAULT_END2END_MAX_DET})",
    )
    p.add_argument("--int8", action="store_true", help="INT8 Q/DQ, calibrated and gated")
    p.add_argument(
        "--int8-target",
        default=None,
        choices=INT8_TARGETS,
        help=f"--int8: the runtime the file is for (default {DEFAULT_INT8_TARGET}); "
        "docs/int8.md says which file for which runtime",
    )
    p.add_argument("--calib", default=None, help="--int8: DATA.yaml (val split) or image folder")
    p.add_argument(
        "--calib-images", type=count(1), default=None, help="--int8: frames (default: up to 300)"
    )
    p.add_argument("--calib-method", default="minmax", choices=CALIB_METHODS)
    p.add_argument(
        "--int8-max-drop",
        type=number(0),
        default=DEFAULT_MAX_DROP,
        help="--int8: most box/mask mAP50-95 points INT8 may lose against FP32",
    )
    p.add_argument(
        "--int8-val",
        default=None,
        help="--int8: DATA.yaml to gate on (needed if --calib is a folder)",
    )
    p.add_argument(
        "--calibrate-masking",
        type=float,
        nargs="?",
        const=DEFAULT_BUDGET_S,
        default=None,
        metavar="SECONDS",
        help="then choose the model's own masking settings (slimseg calibrate, within SECONDS; "
        f"default {DEFAULT_BUDGET_S:g}) and write them into the export as its 'calibrated' "
        "preset (raw FP32/FP16 exports; needs slimseg[calibrate] and, for the ORB-SLAM3 "
        "confirmation, slimseg[slam])",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--out", default=None, help="output .onnx (default export/<model>.onnx)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.int8 and (args.half or args.dynamic):
        raise SlimsegError("--int8 goes without --half and --dynamic (a static FP32-IO graph)")
    if args.int8 and args.end2end:
        raise SlimsegError(
            "--end2end goes without --int8: the INT8 flow quantizes the raw graph only; export "
            "--int8 for the network and run NMS in the runtime, or --end2end [--half]"
        )
    if not args.end2end and (args.conf is not None or args.iou is not None or args.max_det):
        raise SlimsegError("--conf, --iou and --max-det only apply with --end2end")
    if args.end2end:
        check_end2end_size(args.max_det or DEFAULT_END2END_MAX_DET, args.imgsz)
    if args.calibrate_masking is not None and (args.int8 or args.end2end):
        raise SlimsegError("--calibrate-masking calibrates a raw FP32/FP16 export: drop --int8 / "
                           "--end2end, or run slimseg calibrate on the raw export")  # fmt: skip
    if args.calibrate_masking is not None and not args.calibrate_masking > 0:
        raise SlimsegError(f"--calibrate-masking {args.calibrate_masking}: expected seconds > 0")
    if args.int8 and not args.calib:
        raise SlimsegError("--int8 needs --calib DATA.yaml or --calib FOLDER of frames")
    if not args.int8 and (args.calib or args.calib_images or args.int8_val or args.int8_target):
        raise SlimsegError(
            "--calib, --calib-images, --int8-val and --int8-target only apply with --int8"
        )
    source = Path(args.weights)
    if source.suffix in (".pt", ".ckpt"):
        model, info = load_weights(source)
        names, mobility = info.names, info.mobility
    else:
        model = build_model(args.weights, num_classes=args.nc).eval()
        names, mobility = [], []
    if len(args.imgsz) > 2:
        raise SlimsegError(f"--imgsz {' '.join(map(str, args.imgsz))}: give H, or H W")
    imgsz = (args.imgsz[0], args.imgsz[-1])
    target = args.int8_target or DEFAULT_INT8_TARGET
    int8_suffix = "-int8" if target == DEFAULT_INT8_TARGET else "-int8-ort"
    suffix = ("-e2e" if args.end2end else "") + (
        "-fp16" if args.half else int8_suffix if args.int8 else ""
    )
    out = Path(args.out) if args.out else Path("export") / f"{model.spec.name}{suffix}.onnx"
    inputs = {"--weights": args.weights, "--calib": args.calib, "--int8-val": args.int8_val}
    for written in (out, sidecar_path(out)):  # the graph and its sidecar
        refuse_inputs(written, "--out", inputs)
    if args.int8:
        return _run_int8(args, model, out, imgsz, names, mobility)
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
        end2end=_end2end_settings(args),
    )
    print(f"wrote {report.path} ({report.precision}, opset {report.opset}, {report.nodes} nodes)")
    print(f"  metadata sidecar {report.sidecar}")
    print(f"  ops: {', '.join(report.ops)}")
    print("  parity vs fused torch: " + ", ".join(f"{k} {v:.3g}" for k, v in report.parity.items()))
    if args.calibrate_masking is not None:
        _calibrate_masking(report.path, args.calibrate_masking, not args.quiet)
    return 0


def _calibrate_masking(path: Path, budget_s: float, progress: bool) -> None:
    """Calibrate the export ``path`` into a staged copy, then put the copy (and its sidecar)
    in its place: the export carries its ``calibrated`` preset; the report lands beside it."""
    import os

    from slimseg.calibrate.run import CalibrationPlan
    from slimseg.cli.calibrate import calibrate_model, default_report

    staged = path.with_name(f".{path.stem}.calibrated.onnx")
    report = default_report(path)
    plan = CalibrationPlan(model=path, budget_s=budget_s, progress=progress)
    try:
        print(calibrate_model(plan, staged, report, print).replace(str(staged), str(path)))
        os.replace(sidecar_path(staged), sidecar_path(path))
        os.replace(staged, path)
    finally:
        for p in (staged, sidecar_path(staged)):
            p.unlink(missing_ok=True)


def _end2end_settings(args: argparse.Namespace) -> End2EndSettings | None:
    if not args.end2end:
        return None
    conf = DEFAULT_END2END_CONF if args.conf is None else args.conf
    iou = DEFAULT_END2END_IOU if args.iou is None else args.iou
    return End2EndSettings(conf=conf, iou=iou, max_det=args.max_det or DEFAULT_END2END_MAX_DET)


def _run_int8(args, model, out: Path, imgsz, names, mobility) -> int:
    report = export_int8(
        model,
        out,
        args.calib,
        imgsz,
        names,
        mobility,
        calib_images=args.calib_images,
        method=args.calib_method,
        max_drop=args.int8_max_drop,
        val_data=args.int8_val,
        opset=args.opset,
        progress=not args.quiet,
        target=args.int8_target or DEFAULT_INT8_TARGET,
    )
    print(f"wrote {report.path} (int8 Q/DQ for {report.target}, {report.nodes} nodes)")
    print(f"  metadata sidecar {report.sidecar}")
    skipped = f", {report.calib_skipped} unreadable skipped" if report.calib_skipped else ""
    print(f"  calibration: {report.calib_images} images, {args.calib_method}{skipped}")
    print("  placement: " + ", ".join(f"{k} {v}" for k, v in report.placement.items()))
    fp, q = report.map_fp32, report.map_int8
    print(
        "  mAP50-95 FP32 -> INT8: "
        + ", ".join(f"{k} {fp[k]:.2f} -> {q[k]:.2f}" for k in fp)
        + f" (max drop {args.int8_max_drop})"
    )
    a = report.agreement
    print(
        f"  agreement with FP32 on {a['frames']} calibration frames: {a['matched']}/{a['checked']}"
        f" candidate detections matched, min IoU {a['min_iou']:.3f}, max score diff "
        f"{a['max_score_diff']:.3g}"
        + (f", NMS survivors matched {a['nms_matched']:.1%}" if "nms_matched" in a else "")
    )
    return 0
