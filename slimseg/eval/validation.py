"""Validation shared by training and ``slimseg val``: batches → frame detections → COCO mAP;
for semantic models (and YOLO segmenters with ``semantic=True``): class maps → mIoU / MPA.

Semantic metrics are computed on the network-input grid of the letterboxed validation images
(the letterbox padding is ignored), so MSNET's logits and a YOLO segmenter's instance masks
(painted into a class map by ascending confidence) are scored on exactly the same pixels.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader
from tqdm import tqdm

from slimseg.data.collate import make_collate, network_input
from slimseg.data.dataset import ZooDataset
from slimseg.data.semantic import instances_to_semantic
from slimseg.detections import FrameDetections
from slimseg.errors import SlimsegError
from slimseg.eval.coco_eval import CocoEvaluator
from slimseg.eval.mask_quality import evaluator_mask_quality
from slimseg.eval.postprocess import COCO_MAX_DETS, batch_to_frame_detections
from slimseg.eval.semantic_metrics import ConfusionMatrix
from slimseg.models.registry import detection_rows
from slimseg.ops.masks import assemble_masks
from slimseg.ops.nms import EVAL_CONF, MAX_DET, NMS_IOU, non_max_suppression

# Score threshold of a YOLO segmenter's detections painted into a class map (the predict
# default): the 0.001 of mAP evaluation would paint every low-score guess.
SEMANTIC_CONF = 0.25


def is_semantic(model: nn.Module) -> bool:
    """True for per-pixel class models (MSNET)."""
    return model.spec.task == "semantic"


@torch.no_grad()
def semantic_batch(
    model: nn.Module,
    batch: dict,
    conf: float = SEMANTIC_CONF,
    iou: float = NMS_IOU,
    max_det: int = MAX_DET,
    timings: dict[str, float] | None = None,
) -> torch.Tensor:
    """Class maps ``int64 [B, H, W]`` (0 = background, class + 1) on the network input.

    Semantic models: argmax of the logits. YOLO segmenters: NMS (``conf``, ``iou``), masks
    at input resolution, painted by ascending confidence
    (:func:`~slimseg.data.semantic.instances_to_semantic`).
    """
    images = network_input(batch["images"], _device(model))
    t0 = time.perf_counter()
    out = model(images)
    t1 = time.perf_counter()
    if is_semantic(model):
        maps = out.argmax(dim=1).cpu()
    else:
        if not (isinstance(out, tuple) and model.spec.task == "segment"):
            raise SlimsegError(f"{model.spec.name} is not a segmenter: semantic metrics need masks")
        pred, proto = out
        dets = non_max_suppression(pred, model.num_classes, conf=conf, iou=iou, max_det=max_det)
        hw = tuple(images.shape[2:])
        maps_np = []
        for d, pr in zip(dets, proto, strict=True):
            masks = assemble_masks(d.coeffs, pr, d.boxes, hw).cpu().numpy()
            maps_np.append(
                instances_to_semantic(masks, d.classes.cpu().numpy(), d.scores.cpu().numpy())
            )
        maps = torch.from_numpy(np.stack(maps_np))
    _add_timings(timings, t0, t1)
    return maps


def validate_semantic(
    model: nn.Module,
    loader: Iterable[dict],
    names: list[str] | None = None,
    conf: float = SEMANTIC_CONF,
    iou: float = NMS_IOU,
    max_det: int = MAX_DET,
    progress: bool = True,
) -> tuple[dict, ConfusionMatrix]:
    """mIoU / MPA (:mod:`slimseg.eval.semantic_metrics`) of ``model`` over ``loader``, whose
    batches carry ``semantic`` targets; adds ``speed_ms`` per image."""
    was_training = model.training
    model.eval()
    matrix = ConfusionMatrix(model.num_classes + 1)
    timings: dict[str, float] = {}
    images = 0
    for batch in tqdm(loader, desc="val", disable=not progress, leave=False):
        maps = semantic_batch(model, batch, conf, iou, max_det, timings)
        matrix.update(maps, batch["semantic"])
        images += len(maps)
    model.train(was_training)
    result = matrix.compute(names)
    result["speed_ms"] = {k: 1000 * v / max(images, 1) for k, v in timings.items()}
    return result, matrix


@torch.no_grad()
def detect_batch(
    model: nn.Module,
    batch: dict,
    conf: float = EVAL_CONF,
    iou: float = NMS_IOU,
    max_det: int = MAX_DET,
    timings: dict[str, float] | None = None,
    mask_limit: int | None = COCO_MAX_DETS,
) -> list[FrameDetections]:
    """Run an eval-mode model on a collate batch; detections in each source frame, masks
    as RLEs (only for the first ``mask_limit`` detections of each class: the ones COCO
    mAP reads; ``None``: all).

    ``timings`` (optional) accumulates ``inference`` and ``postprocess`` seconds.
    """
    images = network_input(batch["images"], _device(model))
    t0 = time.perf_counter()
    out = model(images)
    t1 = time.perf_counter()
    pred, proto = out if isinstance(out, tuple) else (out, None)
    pred = detection_rows(model.spec.family, pred)
    dets = non_max_suppression(pred, model.num_classes, conf=conf, iou=iou, max_det=max_det)
    frames = batch_to_frame_detections(dets, proto, batch["meta"], rle=True, mask_limit=mask_limit)
    _add_timings(timings, t0, t1)
    return frames


def _device(model: nn.Module) -> torch.device:
    """Where the model's inputs go: its parameters' device (CPU for a graph run by
    onnxruntime, :class:`~slimseg.deploy.onnx_model.OnnxModel`, which has none)."""
    first = next(model.parameters(), None)
    return torch.device("cpu") if first is None else first.device


def _add_timings(timings: dict[str, float] | None, t0: float, t1: float) -> None:
    """Accumulate ``inference`` (t0→t1) and ``postprocess`` (t1→now) seconds."""
    if timings is not None:
        timings["inference"] = timings.get("inference", 0.0) + t1 - t0
        timings["postprocess"] = timings.get("postprocess", 0.0) + time.perf_counter() - t1


def validate_loader(
    model: nn.Module,
    loader: Iterable[dict],
    evaluator: CocoEvaluator,
    conf: float = EVAL_CONF,
    iou: float = NMS_IOU,
    max_det: int = MAX_DET,
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


def validate_dataset(
    model: nn.Module,
    dataset: ZooDataset,
    batch: int = 8,
    workers: int = 0,
    conf: float = EVAL_CONF,
    iou: float = NMS_IOU,
    progress: bool = True,
    semantic: bool = False,
) -> tuple[dict, CocoEvaluator | ConfusionMatrix]:
    """COCO mAP of ``model`` on a validation ``ZooDataset`` (letterbox only) over its json.

    Semantic models (MSNET), or any segmenter with ``semantic=True``, are scored with mIoU /
    MPA instead (:func:`validate_semantic`; ``conf`` then thresholds the painted detections
    of a YOLO segmenter); the second item is then the accumulated ``ConfusionMatrix``.
    """
    semantic = semantic or is_semantic(model)
    collate = make_collate(semantic=semantic)
    loader = DataLoader(dataset, batch_size=batch, num_workers=workers, collate_fn=collate)
    if semantic:
        names = list(getattr(dataset.base, "names", []) or []) or None
        return validate_semantic(model, loader, names, conf, iou, progress=progress)
    evaluator = CocoEvaluator.from_dataset(dataset.base, iou_types_for(model))
    return validate_loader(model, loader, evaluator, conf, iou, progress=progress), evaluator


def validate_mask_quality(
    model: nn.Module,
    dataset: ZooDataset,
    batch: int = 8,
    workers: int = 0,
    conf: float = EVAL_CONF,
    iou: float = NMS_IOU,
    progress: bool = False,
    **options: Any,
) -> dict:
    """Mask quality (:func:`~slimseg.eval.mask_quality.mask_quality`: per-class mask AP,
    Boundary AP, person skeleton recall) of a segmenter on a validation ``ZooDataset``
    (letterbox only), e.g. a trained sweep variant's val split; ``options`` go to
    ``mask_quality`` (``narrow_bands``, ``dilation_ratio``, ``thin_width``, ...)."""
    if model.spec.task != "segment":
        raise SlimsegError(f"{model.spec.name} has no instance masks: mask quality needs them")
    _, evaluator = validate_dataset(model, dataset, batch, workers, conf, iou, progress)
    return evaluator_mask_quality(evaluator, **options)
