"""Validation shared by training and ``slimseg val``: batches → frame detections → COCO mAP."""

from __future__ import annotations

import time
from collections.abc import Iterable

import torch
from torch import nn
from torch.utils.data import DataLoader
from tqdm import tqdm

from slimseg.data.collate import make_collate
from slimseg.data.dataset import YoloDataset
from slimseg.eval.coco_eval import CocoEvaluator
from slimseg.eval.postprocess import FrameDetections, batch_to_frame_detections
from slimseg.ops.nms import non_max_suppression, yolov3_to_rows


@torch.no_grad()
def detect_batch(
    model: nn.Module,
    batch: dict,
    conf: float = 0.001,
    iou: float = 0.7,
    max_det: int = 300,
    timings: dict[str, float] | None = None,
) -> list[FrameDetections]:
    """Run an eval-mode model on a collate batch; detections in each source frame.

    ``timings`` (optional) accumulates ``inference`` and ``postprocess`` seconds.
    """
    images = batch["images"].to(next(model.parameters()).device)
    t0 = time.perf_counter()
    out = model(images)
    t1 = time.perf_counter()
    pred, proto = out if isinstance(out, tuple) else (out, None)
    if model.spec.family == "darknet-yolov3":
        pred = yolov3_to_rows(pred)
    dets = non_max_suppression(pred, model.num_classes, conf=conf, iou=iou, max_det=max_det)
    frames = batch_to_frame_detections(dets, proto, batch["meta"], rle=True)
    if timings is not None:
        timings["inference"] = timings.get("inference", 0.0) + t1 - t0
        timings["postprocess"] = timings.get("postprocess", 0.0) + time.perf_counter() - t1
    return frames


def evaluate(
    model: nn.Module,
    loader: Iterable[dict],
    evaluator: CocoEvaluator,
    conf: float = 0.001,
    iou: float = 0.7,
    max_det: int = 300,
    progress: bool = True,
) -> dict:
    """COCO box/mask mAP of ``model`` over ``loader``; adds ``speed_ms`` per image."""
    was_training = model.training
    model.eval()
    evaluator.reset()
    timings: dict[str, float] = {}
    images = 0
    for batch in tqdm(loader, desc="val", disable=not progress, leave=False):
        frames = detect_batch(model, batch, conf, iou, max_det, timings)
        evaluator.update(batch["image_ids"], frames)
        images += len(frames)
    model.train(was_training)
    result = evaluator.summarize()
    result["speed_ms"] = {k: 1000 * v / max(images, 1) for k, v in timings.items()}
    return result


def iou_types_for(model: nn.Module) -> tuple[str, ...]:
    """COCO iou types a model is scored on: boxes always, masks for segmenters."""
    return ("bbox", "segm") if model.spec.task == "segment" else ("bbox",)


def evaluate_dataset(
    model: nn.Module,
    dataset: YoloDataset,
    batch: int = 8,
    workers: int = 0,
    conf: float = 0.001,
    iou: float = 0.7,
    progress: bool = True,
) -> tuple[dict, CocoEvaluator]:
    """COCO mAP of ``model`` on a validation ``YoloDataset`` (letterbox only) over its json."""
    loader = DataLoader(dataset, batch_size=batch, num_workers=workers, collate_fn=make_collate())
    evaluator = CocoEvaluator.from_dataset(dataset.base, iou_types_for(model))
    return evaluate(model, loader, evaluator, conf, iou, progress=progress), evaluator
