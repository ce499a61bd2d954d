"""COCO run-length encoding of masks that are zero outside a small window.

A COCO RLE walks the frame column by column (column-major) and alternates run lengths of 0
and 1 pixels, starting with 0s. Validation masks are zero outside their detection's window,
so the run boundaries can be read off the windows alone, for every mask of a chunk in a few
tensor operations (on the masks' device), without ever building a full-frame mask; only the
final string compression is pycocotools' (one C call for the whole list). The result is the
same string :func:`pycocotools.mask.encode` gives for the full-frame mask.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from pycocotools import mask as mask_utils


def window_rles(
    values: torch.Tensor, top: torch.Tensor, left: torch.Tensor, frame_hw: tuple[int, int]
) -> list[dict]:
    """COCO RLEs (``size [h, w]``, ``counts`` str) of ``m`` masks on a ``frame_hw`` frame.

    ``values``: ``bool [m, sy, sx]``, mask ``d`` on the window whose top-left pixel is
    ``(top[d], left[d])`` (``int64 [m]``); the mask is 0 outside its window. Window pixels
    outside the frame must be ``False`` (they are then ignored).
    """
    h, w = frame_hw
    m = values.shape[0]
    if m == 0:
        return []
    # columns of each window, padded with a 0 pixel above and below: [m, sx, sy + 2]
    columns = F.pad(values.transpose(1, 2).to(torch.int8), (1, 1))
    k, c, r = (columns[:, :, 1:] != columns[:, :, :-1]).nonzero(as_tuple=True)
    # a change between padded rows r and r + 1 starts or ends a run at window row r
    flat = (left[k] + c) * h + top[k] + r  # column-major frame index, sorted within each mask
    # a run reaching the bottom of a column and one starting at the top of the next are one
    # run in the frame: their shared boundary appears twice, drop both copies
    same = (flat[1:] == flat[:-1]) & (k[1:] == k[:-1])
    drop = torch.zeros_like(flat, dtype=torch.bool)
    drop[1:] |= same
    drop[:-1] |= same
    k, flat = k[~drop].cpu().numpy(), flat[~drop].cpu().numpy()
    # mask d's boundaries flat[s_d:e_d], framed by 0 and h·w: its run lengths are the gaps
    first = np.searchsorted(k, np.arange(m))
    last = np.append(first[1:], len(flat))
    at = np.stack((first, last), 1).reshape(-1)  # non-decreasing: inserted in this order
    framed = np.insert(flat, at, np.tile([0, h * w], m))
    gaps = np.diff(framed)  # per mask its run lengths, then one junk gap (h·w → 0)
    cuts = np.stack((last + 2 * np.arange(m) + 1, last + 2 * np.arange(m) + 2), 1)
    objs = []
    for counts in np.split(gaps, cuts.reshape(-1)[:-1])[::2]:
        if len(counts) > 1 and counts[-1] == 0:  # the last run ends at the last pixel
            counts = counts[:-1]
        objs.append({"size": [h, w], "counts": counts})
    rles = mask_utils.frPyObjects(objs, h, w)
    for rle in rles:
        rle["counts"] = rle["counts"].decode("ascii")
    return rles
