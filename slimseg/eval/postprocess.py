"""NMS output (network-input pixels) → detections on the source frame (val and predict).

Boxes go through :func:`~slimseg.data.letterbox.boxes_to_frame` (undo padding and scale, clip
to the frame). Masks: :func:`~slimseg.ops.masks.assemble_masks` gives probabilities at input
resolution, :func:`~slimseg.ops.masks.masks_to_frame` removes the padding, resizes them to the
frame and thresholds at 0.5. Masks can be kept dense (``bool [N, h, w]``) or as COCO RLEs
(compact: what validation accumulates over a whole dataset).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from pycocotools import mask as mask_utils

from slimseg.data.letterbox import LetterboxParams, boxes_to_frame
from slimseg.ops.masks import assemble_masks, masks_to_frame
from slimseg.ops.nms import Detections


@dataclass(eq=False)
class FrameDetections:
    """Detections of one image in source-frame pixels, sorted by decreasing score.

    ``boxes``: ``float32 [N, 4]`` xyxy, clipped to the frame; ``scores``: ``float32 [N]``;
    ``classes``: ``int64 [N]`` contiguous class ids; ``masks``: ``bool [N, h, w]`` or
    ``None``; ``rles``: ``N`` COCO RLE dicts (``size [h, w]``, ``counts`` str) or ``None``;
    ``image_hw``: ``(h, w)``. Detection-only results have neither masks nor RLEs.
    """

    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray
    image_hw: tuple[int, int]
    masks: np.ndarray | None = None
    rles: list[dict] | None = None

    def __len__(self) -> int:
        return len(self.scores)

    @property
    def has_masks(self) -> bool:
        return self.masks is not None or self.rles is not None

    def mask_rles(self) -> list[dict]:
        """The masks as COCO RLEs (encoded from ``masks`` if only those are stored)."""
        if self.rles is not None:
            return self.rles
        if self.masks is None:
            raise ValueError("these detections have no masks (detection-only model)")
        return encode_rle(self.masks)

    def dense_masks(self) -> np.ndarray:
        """The masks as ``bool [N, h, w]`` (decoded from ``rles`` if only those are stored)."""
        if self.masks is not None:
            return self.masks
        if self.rles is None:
            raise ValueError("these detections have no masks (detection-only model)")
        return decode_rle(self.rles, self.image_hw)

    @classmethod
    def empty(cls, image_hw: tuple[int, int], with_masks: bool = False) -> FrameDetections:
        """No detection (masks ``bool [0, h, w]`` if ``with_masks``)."""
        h, w = image_hw
        return cls(
            boxes=np.zeros((0, 4), np.float32),
            scores=np.zeros(0, np.float32),
            classes=np.zeros(0, np.int64),
            image_hw=(h, w),
            masks=np.zeros((0, h, w), bool) if with_masks else None,
        )


def encode_rle(masks: np.ndarray) -> list[dict]:
    """``bool/uint8 [N, h, w]`` → ``N`` COCO RLE dicts (``counts`` as str, json-ready)."""
    if len(masks) == 0:
        return []
    # [N, w, h] C order is [h, w, N] Fortran order: one transpose copy per mask.
    fortran = np.ascontiguousarray(np.transpose(masks, (0, 2, 1)), dtype=np.uint8).T
    rles = mask_utils.encode(fortran)
    for r in rles:
        r["counts"] = r["counts"].decode("ascii")
    return rles


def decode_rle(rles: Sequence[dict], image_hw: tuple[int, int]) -> np.ndarray:
    """``N`` COCO RLE dicts → ``bool [N, h, w]``."""
    if len(rles) == 0:
        return np.zeros((0, *image_hw), bool)
    with warnings.catch_warnings():
        # pycocotools' Cython array lacks numpy 2's ``copy`` keyword: harmless, silenced here.
        warnings.filterwarnings("ignore", "__array__ implementation", DeprecationWarning)
        return np.transpose(mask_utils.decode(list(rles)), (2, 0, 1)).astype(bool)


def to_frame_detections(
    dets: Detections,
    proto: torch.Tensor | None,
    meta: dict,
    *,
    rle: bool = False,
    chunk: int = 32,
) -> FrameDetections:
    """One image's NMS output → :class:`FrameDetections` on its source frame.

    ``dets``: boxes xyxy in input pixels and ``coeffs [N, nm]``; ``proto``: the image's
    prototypes ``[nm, Hp, Wp]`` (``None``: detection only, no masks); ``meta``: the batch meta
    of the image, with ``"letterbox"`` (:class:`LetterboxParams`) and ``"orig_shape"``
    ``(h, w)``. ``rle=True`` stores masks as RLEs instead of ``bool [N, h, w]``. Masks are
    built ``chunk`` detections at a time.
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
    # Without a resize to the frame, thresholding at input resolution gives the same masks
    # and skips the float copies.
    threshold = 0.5 if (p.new_h, p.new_w) == (h, w) else None
    parts: list[np.ndarray] = []
    rles: list[dict] = []
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
        m = m.cpu().numpy()
        if rle:
            rles.extend(encode_rle(m))
        else:
            parts.append(m)
    if rle:
        out.rles = rles
    else:
        out.masks = np.concatenate(parts) if parts else np.zeros((0, h, w), bool)
    return out


def batch_to_frame_detections(
    dets: Sequence[Detections],
    proto: torch.Tensor | None,
    metas: Sequence[dict],
    *,
    rle: bool = False,
    chunk: int = 32,
) -> list[FrameDetections]:
    """:func:`to_frame_detections` for a batch: ``proto [B, nm, Hp, Wp]`` or ``None``."""
    if len(dets) != len(metas) or (proto is not None and proto.shape[0] != len(dets)):
        raise ValueError("dets, proto and metas must describe the same batch")
    return [
        to_frame_detections(d, None if proto is None else proto[i], m, rle=rle, chunk=chunk)
        for i, (d, m) in enumerate(zip(dets, metas, strict=True))
    ]
