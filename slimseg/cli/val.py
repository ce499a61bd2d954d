"""``slimseg val``: COCO box and mask mAP of a weights file on a dataset config; mIoU and
MPA for semantic models (MSNET), or for a YOLO segmenter with ``--semantic``. With
``--mask-quality`` also per-class mask AP, Boundary AP and person skeleton recall
(:mod:`slimseg.eval.mask_quality`); ``--ceiling R`` scores the ground truth through an
``R`` times coarser mask grid instead of a model (:mod:`slimseg.eval.ceiling`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from torch import nn

from slimseg.cli.arg_types import FRACTION, count, multiple_of
from slimseg.cli.commands import COMMAND_HELP
from slimseg.data.coco import CocoDataset
from slimseg.data.config import DataConfig, load_data_config
from slimseg.data.dataset import ZooDataset
from slimseg.deploy.engines import ONNX_BACKENDS
from slimseg.deploy.metadata import precision_label
from slimseg.deploy.onnx_model import OnnxModel
from slimseg.errors import SlimsegError
from slimseg.eval.boundary import DILATION_RATIO, NARROW_BANDS
from slimseg.eval.ceiling import ceiling_detections
from slimseg.eval.coco_eval import format_metrics_table, load_gt
from slimseg.eval.mask_quality import (
    evaluator_mask_quality,
    format_mask_quality_table,
    mask_quality,
)
from slimseg.eval.semantic_metrics import format_semantic_table
from slimseg.eval.validation import SEMANTIC_CONF, is_semantic, validate_dataset
from slimseg.models.checkpoint import load_weights
from slimseg.ops.nms import EVAL_CONF, NMS_IOU
from slimseg.utils.outputs import claim_file, json_with, refuse_inputs


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "val",
        help=COMMAND_HELP["val"],
        description="Evaluate weights (.pt from slimseg train, or its .ckpt) or a file written "
        "by slimseg export (FP32, FP16 or INT8 .onnx, run by onnxruntime with the same "
        "letterbox, NMS and masks) with pycocotools; "
        "semantic models (msnet-*) report per-class IoU and pixel accuracy, mIoU and MPA over "
        "the split's confusion matrix. --semantic scores a YOLO segmenter the same way: its "
        "masks (score >= --conf) painted into a class map by ascending confidence.",
    )
    p.add_argument(
        "--weights",
        default=None,
        help="weights/best.pt, checkpoints/last.ckpt or an exported .onnx (required unless "
        "--ceiling)",
    )
    p.add_argument("--data", required=True, help="dataset config YAML")
    p.add_argument("--split", default="val", choices=("val", "train"))
    p.add_argument("--imgsz", type=multiple_of(), default=None, help="default: the training imgsz")
    p.add_argument("--batch", type=count(1), default=8)
    p.add_argument("--workers", type=count(0), default=2)
    p.add_argument(
        "--conf",
        type=FRACTION,
        default=None,
        help=f"score threshold (default {EVAL_CONF} for mAP, {SEMANTIC_CONF} for --semantic)",
    )
    p.add_argument(
        "--semantic",
        action="store_true",
        help="mIoU/MPA of a YOLO segmenter's masks as a class map (implied for msnet)",
    )
    p.add_argument(
        "--mask-quality",
        action="store_true",
        help="also per-class mask AP/AP50/AP75, Boundary AP ("
        + ", ".join(f"{d} px" for d in NARROW_BANDS)
        + f", {100 * DILATION_RATIO:g}%% of the diagonal) and person skeleton recall (all / thin "
        "parts); JSON: under 'mask_quality'",
    )
    p.add_argument(
        "--ceiling",
        type=int,
        default=None,
        metavar="RATIO",
        help="no model: score the ground-truth masks pushed through a RATIO times coarser "
        "mask grid and back (the best masks on that grid can do), with --mask-quality's metrics",
    )
    p.add_argument("--iou", type=FRACTION, default=NMS_IOU)
    p.add_argument("--json", action="store_true", help="print the metrics as JSON")
    p.add_argument("--save-json", default=None, help="also write COCO results json here")
    p.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N (network and masks)")
    p.add_argument(
        "--backend",
        default="onnxruntime",
        choices=ONNX_BACKENDS,
        help="the engine that runs an exported .onnx (openvino: f32; docs/engines.md)",
    )
    p.set_defaults(run=run)


def _load(args: argparse.Namespace) -> tuple[nn.Module, int]:
    """The model to score and its input size: torch weights (fused) or an exported graph."""
    if Path(args.weights).suffix.lower() != ".onnx":
        if args.backend != "onnxruntime":
            raise SlimsegError(
                f"--backend {args.backend} runs an exported .onnx, not {args.weights}"
            )
        model, info = load_weights(args.weights, fused=True)
        return model, args.imgsz or int(info.train_config.get("imgsz", 640))
    graph = OnnxModel(args.weights, backend=args.backend)
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
    if args.ceiling is not None:
        return _run_ceiling(args)
    if args.weights is None:
        raise SlimsegError("--weights is required (or --ceiling RATIO to score the mask grid)")
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
    if args.mask_quality and (semantic or model.spec.task != "segment"):
        raise SlimsegError(
            f"--mask-quality scores instance masks: not available for "
            f"{'mIoU/MPA' if semantic else f'the detector {model.spec.name}'}"
        )
    if args.save_json:  # before the work: never over an input or a file val did not write
        _claim_save_json(args, data_cfg)
    conf = args.conf if args.conf is not None else (SEMANTIC_CONF if semantic else EVAL_CONF)
    base = CocoDataset.from_config(data_cfg, args.split)
    result, evaluator = validate_dataset(
        model,
        ZooDataset(base, imgsz),
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
    if args.mask_quality:
        result["mask_quality"] = evaluator_mask_quality(evaluator)
    if args.json:
        print(json.dumps(result))
    else:
        what = ""
        if isinstance(model, OnnxModel):
            engine = "" if model.backend == "onnxruntime" else f", {model.backend}"
            what = f" ({precision_label(model.metadata)}{engine})"
        print(
            f"{model.spec.name}{what} on {args.data} ({args.split}, {len(base)} images, {imgsz} px)"
        )
        print(format_metrics_table(result, data_cfg.names))
        speed = ", ".join(f"{k} {v:.1f} ms" for k, v in result["speed_ms"].items())
        print(f"speed per image: {speed}")
        if args.mask_quality:
            print("mask quality (mask AP and Boundary AP at three band widths):")
            print(format_mask_quality_table(result["mask_quality"]))
    return 0


def _claim_save_json(args: argparse.Namespace, data_cfg: DataConfig) -> None:
    """``--save-json`` is neither an input (the data yaml, the weights, any split's
    annotations) nor an existing file other than a COCO results list."""
    inputs: dict = {"--data": args.data, "--weights": args.weights}
    for name, split in (("train", data_cfg.train), ("val", data_cfg.val)):
        if split is not None:
            inputs[f"the {name} split's annotations"] = [p.annotations for p in split.parts]
    refuse_inputs(args.save_json, "--save-json", inputs)
    claim_file(args.save_json, "--save-json", lambda p: json_with(p, list), "COCO results file")


def _run_ceiling(args: argparse.Namespace) -> int:
    """``--ceiling R``: mask quality of the ground truth through an ``R``-coarser grid."""
    given = [f for f, v in (("--weights", args.weights), ("--save-json", args.save_json)) if v]
    given += ["--semantic"] if args.semantic else []
    if given:
        raise SlimsegError(f"--ceiling scores the ground truth, not a model: drop {given[0]}")
    if args.ceiling < 1:
        raise SlimsegError(f"--ceiling {args.ceiling}: the grid ratio must be >= 1 (e.g. 4)")
    base = CocoDataset.from_config(load_data_config(args.data), args.split)
    gt = load_gt(base.ground_truth)
    image_ids = [rec.id for rec in base.records]
    dets = ceiling_detections(gt, args.ceiling, image_ids)
    quality = mask_quality(gt, dets, image_ids=image_ids, cat_ids=base.cat_ids)
    if args.json:
        print(json.dumps({"ceiling_ratio": args.ceiling, "mask_quality": quality}))
        return 0
    print(
        f"ceiling: ground-truth masks through a {args.ceiling}x coarser grid and back, "
        f"{args.data} ({args.split}, {len(base)} images)"
    )
    print(format_mask_quality_table(quality))
    return 0


def _nan_to_none(value: object) -> object:
    if isinstance(value, float) and value != value:
        return None
    if isinstance(value, dict):
        return {k: _nan_to_none(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_nan_to_none(v) for v in value]
    return value
