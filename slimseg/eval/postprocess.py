"""NMS output (network-input pixels) → detections on the source frame (val and predict).

Boxes go through :func:`~slimseg.ops.letterbox.boxes_to_frame` (undo padding and scale, clip
to the frame). Masks: :func:`~slimseg.ops.masks.assemble_masks` gives probabilities at input
resolution, :func:`~slimseg.ops.masks.masks_to_frame` removes the padding, resizes them to the
frame and thresholds at 0.5. Masks can be kept dense (``bool [N, h, w]``) or as COCO RLEs
(compact: what validation accumulates over a whole dataset).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from slimseg.detections import Detections, FrameDetections
from slimseg.ops.letterbox import LetterboxParams, boxes_to_frame
from slimseg.ops.masks import assemble_masks, mask_windows, masks_to_frame, window_to_frame
from slimseg.ops.rle import window_rles

#: COCO scores at most this many detections per image and class (``COCOeval.params.maxDets``
#: last value): validation assembles masks only for detections within it, in score order.
COCO_MAX_DETS = 100


def within_class_limit(classes: torch.Tensor, limit: int | None) -> torch.Tensor:
    """``bool [N]``: detections (sorted by decreasing score) among the first ``limit`` of
    their class; all of them when ``limit`` is ``None``."""
    if limit is None or len(classes) == 0:
        return torch.ones(len(classes), dtype=torch.bool, device=classes.device)
    onehot = F.one_hot(classes.long(), int(classes.max()) + 1)
    rank = (onehot.cumsum(0) * onehot).sum(1) - 1  # earlier detections of the same class
    return rank < limit


def to_frame_detections(
    dets: Detections,
    proto: torch.Tensor | None,
    meta: dict,
    *,
    rle: bool = False,
    chunk: int = 32,
    mask_limit: int | None = None,
) -> FrameDetections:
    """One image's NMS output → :class:`FrameDetections` on its source frame.

    ``dets``: boxes xyxy in input pixels and ``coeffs [N, nm]``; ``proto``: the image's
    prototypes ``[nm, Hp, Wp]`` (``None``: detection only, no masks); ``meta``: the batch meta
    of the image, with ``"letterbox"`` (:class:`LetterboxParams`) and ``"orig_shape"``
    ``(h, w)``. ``rle=True`` stores masks as RLEs instead of ``bool [N, h, w]``, encoded
    from each detection's window (never a full-frame mask); then ``mask_limit`` (e.g.
    :data:`COCO_MAX_DETS`) assembles masks only for the first ``mask_limit`` detections of
    each class, the others' RLE is ``None``. Masks are built ``chunk`` detections at a time,
    on ``proto``'s device.
    """
    p: LetterboxParams = meta["letterbox"]
    h, w = (int(v) for v in meta["orig_shape"])
    boxes_in = dets.boxes.detach()
    out = FrameDetections(
        boxes=boxes_to_frame(boxes_in.float().cpu().numpy().reshape(-1, 4), p, h, w),
        scores=dets.scores.detach().float().cpu().numpy(),
        classes=dets.classes.detach().cpu().numpy().astype(np.int64),
        image_hw=(h, w),
    )
    if proto is None:
        return out
    if dets.coeffs.shape[1] != proto.shape[0]:
        raise ValueError(
            f"proto has {proto.shape[0]} channels but detections carry "
            f"{dets.coeffs.shape[1]} mask coefficients"
        )
    if rle:
        out.rles = _frame_rles(dets, proto.detach(), p, (h, w), chunk, mask_limit)
        return out
    # Without a resize to the frame, thresholding at input resolution gives the same masks
    # and skips the float copies.
    threshold = 0.5 if (p.new_h, p.new_w) == (h, w) else None
    parts: list[np.ndarray] = []
    for s in range(0, len(dets), chunk):
        at_input = assemble_masks(
            dets.coeffs[s : s + chunk].detach(),
            proto.detach(),
            boxes_in[s : s + chunk],
            (p.out_h, p.out_w),
            threshold=threshold,
            chunk=chunk,
        )
        m = masks_to_frame(at_input, p, (h, w), chunk=chunk, boxes=boxes_in[s : s + chunk])
        parts.append(m.cpu().numpy())
    out.masks = np.concatenate(parts) if parts else np.zeros((0, h, w), bool)
    return out


def _frame_rles(
    dets: Detections,
    proto: torch.Tensor,
    p: LetterboxParams,
    frame_hw: tuple[int, int],
    chunk: int,
    mask_limit: int | None,
) -> list[dict | None]:
    """The RLE of each detection's frame mask (``None`` beyond ``mask_limit`` per class):
    the same pixels as the dense path of :func:`to_frame_detections`, from windows."""
    h, w = frame_hw
    rles: list[dict | None] = [None] * len(dets)
    idx = within_class_limit(dets.classes, mask_limit).nonzero().squeeze(1)
    coeffs, boxes = dets.coeffs.detach()[idx], dets.boxes.detach()[idx]
    if (p.new_h, p.new_w) == (h, w):  # no resize: input-resolution windows, minus the padding
        # a box clipped to the frame's part of the input crops the same frame pixels, and
        # leaves every window pixel in the padding False (as window_rles needs)
        lo = torch.tensor([p.left, p.top, p.left, p.top], device=boxes.device, dtype=torch.float32)
        hi = lo + torch.tensor([w, h, w, h], device=boxes.device, dtype=torch.float32)
        boxes = torch.minimum(torch.maximum(boxes.float(), lo), hi)
        for k, values, top, left in mask_windows(coeffs, proto, boxes, (p.out_h, p.out_w)):
            top, left = top - p.top, left - p.left  # frame pixels
            encoded = window_rles(values, top, left, (h, w))
            for i, r in zip(idx[k].tolist(), encoded, strict=True):
                rles[i] = r
        return rles
    hw_in = (p.out_h, p.out_w)
    for k, probs, top, left in mask_windows(coeffs, proto, boxes, hw_in, None, chunk):
        values, top, left = window_to_frame(probs, top, left, p, (h, w), boxes[k])
        for i, r in zip(idx[k].tolist(), window_rles(values, top, left, (h, w)), strict=True):
            rles[i] = r
    return rles


def batch_to_frame_detections(
    dets: Sequence[Detections],
    proto: torch.Tensor | None,
    metas: Sequence[dict],
    *,
    rle: bool = False,
    chunk: int = 32,
    mask_limit: int | None = None,
) -> list[FrameDetections]:
    """:func:`to_frame_detections` for a batch: ``proto [B, nm, Hp, Wp]`` or ``None``."""
    if len(dets) != len(metas) or (proto is not None and proto.shape[0] != len(dets)):
        raise ValueError("dets, proto and metas must describe the same batch")
    return [
        to_frame_detections(
            d,
            None if proto is None else proto[i],
            m,
            rle=rle,
            chunk=chunk,
            mask_limit=mask_limit,
        )
        for i, (d, m) in enumerate(zip(dets, metas, strict=True))
    ]


def outputs_to_frame_detections(
    pred: torch.Tensor,
    proto: torch.Tensor | None,
    metas: Sequence[dict],
    family: str,
    nc: int,
    conf: float,
    iou: float,
    max_det: int,
) -> list[FrameDetections]:
    """A predictor's network outputs (``pred [B, 4 + nc (+ nm), A]``, ``proto [B, nm, Hp, Wp]``
    or ``None``) → dense :class:`FrameDetections` per frame by the torch path validation
    runs (:func:`~slimseg.ops.nms.non_max_suppression`, :func:`to_frame_detections`): the
    reference the runtime's numpy post-processing (``slimseg.deploy.predict_postprocess``)
    is compared with (``tests/deploy/test_postprocess_numpy.py``,
    ``benchmarks/postprocess_numpy.py``)."""
    from slimseg.models.registry import detection_rows
    from slimseg.ops.nms import non_max_suppression

    dets = non_max_suppression(
        detection_rows(family, pred), nc, conf=conf, iou=iou, max_det=max_det
    )
    return batch_to_frame_detections(dets, proto, metas)
