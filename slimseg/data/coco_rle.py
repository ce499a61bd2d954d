"""Instance masks from COCO segmentations: polygons and RLE → one RLE, dense masks, areas."""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import cv2
import numpy as np
from pycocotools import mask as mask_utils

from slimseg.data.coco_index import Instance
from slimseg.ops.box_pixels import box_pixel_bounds


def _box_pixels(box: tuple[float, ...], height: int, width: int) -> tuple[int, int, int, int]:
    """Rows ``r0:r1`` and columns ``c0:c1`` of a box-only instance's mask: the pixel-centre
    rule (``docs/conventions.md`` §1), widened to at least one pixel inside the image."""
    r0, r1, c0, c1 = box_pixel_bounds(box, height, width)
    c0, r0 = min(c0, width - 1), min(r0, height - 1)
    return r0, max(r1, r0 + 1), c0, max(c1, c0 + 1)


def segm_to_rle(segm: list | dict, height: int, width: int) -> dict:
    """Polygons (merged), uncompressed or compressed RLE → one compressed RLE."""
    if isinstance(segm, list):
        return mask_utils.merge(mask_utils.frPyObjects(segm, height, width))
    if isinstance(segm["counts"], list):
        return mask_utils.frPyObjects(segm, height, width)
    return segm


def decode_instance_mask(inst: Instance, height: int, width: int) -> np.ndarray:
    """The ``uint8 [H, W]`` 0/1 mask of a parsed instance (filled box for box instances)."""
    segm = inst.segm
    if segm is None:
        r0, r1, c0, c1 = _box_pixels(inst.box, height, width)
        m = np.zeros((height, width), np.uint8)
        m[r0:r1, c0:c1] = 1
        return m
    rle = segm_to_rle(segm, height, width)
    with warnings.catch_warnings():
        # pycocotools' Cython array lacks numpy 2's ``copy`` keyword: harmless, silenced here.
        warnings.filterwarnings("ignore", "__array__ implementation", DeprecationWarning)
        return np.ascontiguousarray(mask_utils.decode(rle), dtype=np.uint8)


def decode_instance_masks(insts: Sequence[Instance], height: int, width: int) -> np.ndarray:
    """``uint8 [N, H, W]``: :func:`decode_instance_mask` of each instance, with one
    pycocotools call for all RLE instances and a SIMD transpose out of its column-major
    layout (the same pixels, several times faster than one decode and copy per mask)."""
    out = np.empty((len(insts), height, width), np.uint8)
    rle_at = [k for k, inst in enumerate(insts) if inst.segm is not None]
    for k, inst in enumerate(insts):
        if inst.segm is None:
            out[k] = decode_instance_mask(inst, height, width)
    if rle_at:
        rles = [segm_to_rle(insts[k].segm, height, width) for k in rle_at]
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "__array__ implementation", DeprecationWarning)
            columns = mask_utils.decode(rles).T  # [N, W, H], C-contiguous
        for j, k in enumerate(rle_at):
            cv2.transpose(columns[j], dst=out[k])
    return out


def instance_area(inst: Instance, height: int, width: int) -> int:
    """Pixel count of an instance's mask, computed on its RLE (no dense decode)."""
    segm = inst.segm
    if segm is None:
        r0, r1, c0, c1 = _box_pixels(inst.box, height, width)
        return (r1 - r0) * (c1 - c0)
    rle = segm_to_rle(segm, height, width)
    return int(mask_utils.area(rle))
