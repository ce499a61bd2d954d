"""``slimseg val``: COCO box and mask mAP of a weights file on a dataset config; mIoU and
MPA for semantic models (MSNET), or for a YOLO segmenter with ``--semantic``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from torch import nn

from slimseg.data.coco import CocoDataset
from slimseg.data.config import load_data_config
from slimseg.data.dataset import YoloDataset
from slimseg.deploy.checkpoint import load_weights
from slimseg.deploy.onnx_model import OnnxModel
from slimseg.engine.evaluate import SEMANTIC_CONF, evaluate_dataset, is_semantic
from slimseg.errors import SlimsegError
from slimseg.eval.coco_eval import format_metrics_table
from slimseg.eval.semantic_metrics import format_semantic_table
from slimseg.ops.nms import EVAL_CONF, NMS_IOU


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "val",
        help="COCO box/mask mAP (or mIoU/MPA) of weights or an exported ONNX on a val split",
        description="Evaluate weights (.pt from slimseg train, or its .ckpt) or a file written "
        "by slimseg export (FP32, FP16 or INT8 .onnx, run by onnxruntime with the same "
        "letterbox, NMS and masks) with pycocotools; "
        "semantic models (msnet-*) report per-class IoU and pixel accuracy, mIoU and MPA over "
        "the split's confusion matrix. --semantic scores a YOLO segmenter the same way: its "
        "masks (score >= --conf) painted into a class map by ascending confidence.",
    )
    p.add_argument(
        "--weights",
        required=True,
        help="weights/best.pt, checkpoints/last.ckpt or an exported .onnx",
    )
    p.add_argument("--data", required=True, help="dataset config YAML")
    p.add_argument("--split", default="val", choices=("val", "train"))
    p.add_argument("--imgsz", type=int, default=None, help="default: the training imgsz")
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument(
        "--conf",
        type=float,
        default=None,
        help=f"score threshold (default {EVAL_CONF} for mAP, {SEMANTIC_CONF} for --semantic)",
    )
    p.add_argument(
        "--semantic",
        action="store_true",
        help="mIoU/MPA of a YOLO segmenter's masks as a class map (implied for msnet)",
    )
    p.add_argument("--iou", type=float, default=NMS_IOU)
    p.add_argument("--json", action="store_true", help="print the metrics as JSON")
    p.add_argument("--save-json", default=None, help="also write COCO results json here")
    p.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N (network and masks)")
    p.set_defaults(run=run)


def _load(args: argparse.Namespace) -> tuple[nn.Module, int]:
    """The model to score and its input size: torch weights (fused) or an exported graph."""
    if Path(args.weights).suffix.lower() != ".onnx":
        model, info = load_weights(args.weights, fused=True)
        return model, args.imgsz or int(info.train_config.get("imgsz", 640))
    graph = OnnxModel(args.weights)
    static = graph.static_hw
    if static is not None and static[0] != static[1]:
        raise SlimsegError(
            f"{args.weights}: static {static[0]}x{static[1]} input; val letterboxes to a "
            "square: export with one --imgsz (or --dynamic)"
        )
    if static is not None and args.imgsz not in (None, static[0]):
        raise SlimsegError(
            f"{args.weights}: the graph has a static {static[0]}x{static[1]} input; drop "
            f"--imgsz {args.imgsz} or export with --dynamic"
        )
    return graph, args.imgsz or (static[0] if static else int(graph.metadata["imgsz"][0]))


def run(args: argparse.Namespace) -> int:
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        raise SlimsegError(f"--device {args.device}: no CUDA device is visible to torch")
    try:
        device = torch.device(args.device)
    except RuntimeError:
        raise SlimsegError(f"--device {args.device!r}: expected cpu, cuda or cuda:N") from None
    model, imgsz = _load(args)
    if not isinstance(model, OnnxModel):  # an exported graph runs in onnxruntime on the CPU
        model = model.to(device)
    data_cfg = load_data_config(args.data)
    if len(data_cfg.names) != model.num_classes:
        raise SlimsegError(
            f"{args.data}: {len(data_cfg.names)} classes but {args.weights} predicts "
            f"{model.num_classes}; evaluate on the dataset it was trained for"
        )
    semantic = args.semantic or is_semantic(model)
    if semantic and model.spec.task == "detect":
        raise SlimsegError(
            f"--semantic: {args.weights} is a detector ({model.spec.name}); it needs masks"
        )
    if semantic and args.save_json:
        raise SlimsegError("--save-json writes COCO detections: not available for mIoU/MPA")
    conf = args.conf if args.conf is not None else (SEMANTIC_CONF if semantic else EVAL_CONF)
    base = CocoDataset.from_config(data_cfg, args.split)
    result, evaluator = evaluate_dataset(
        model,
        YoloDataset(base, imgsz),
        args.batch,
        args.workers,
        conf=conf,
        iou=args.iou,
        progress=not args.json,
        semantic=semantic,
    )
    if semantic:
        if args.json:  # undefined per-class values (NaN) as null: strict JSON
            print(json.dumps(_nan_to_none(result)))
            return 0
        how = "" if is_semantic(model) else f", masks with score >= {conf} as a class map"
        print(
            f"{model.spec.name} on {args.data} ({args.split}, {len(base)} images, {imgsz} px{how})"
        )
        print(format_semantic_table(result))
        speed = ", ".join(f"{k} {v:.1f} ms" for k, v in result["speed_ms"].items())
        print(f"speed per image: {speed}")
        return 0
    if args.save_json:
        written = evaluator.write_results(args.save_json)
        if not args.json:
            print(f"COCO results: {written}")
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{model.spec.name} on {args.data} ({args.split}, {len(base)} images, {imgsz} px)")
        print(format_metrics_table(result, data_cfg.names))
        speed = ", ".join(f"{k} {v:.1f} ms" for k, v in result["speed_ms"].items())
        print(f"speed per image: {speed}")
    return 0


def _nan_to_none(value: object) -> object:
    if isinstance(value, float) and value != value:
        return None
    if isinstance(value, dict):
        return {k: _nan_to_none(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_nan_to_none(v) for v in value]
    return value
