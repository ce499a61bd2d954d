"""The box-to-pixel rule (``docs/conventions.md`` §1) on scalars, without torch: the one home
the readers of ground truth (``slimseg.data.coco_rle``), the losses and the runtime share."""

from __future__ import annotations

import math
from collections.abc import Sequence


def box_pixel_bounds(box: Sequence[float], height: int, width: int) -> tuple[int, int, int, int]:
    """Pixels of an xyxy box as ``(r0, r1, c0, c1)`` slices: the one box-to-pixel rule.

    A pixel belongs to the box when its centre does: column ``c`` iff ``x0 <= c + 0.5 < x1``,
    i.e. ``c0 = ceil(x0 - 0.5)``, ``c1 = ceil(x1 - 0.5)`` (rows alike), clipped to the image
    (``docs/conventions.md`` §1). The slices may be empty.
    """
    x0, y0, x1, y1 = (float(v) for v in box)
    c0 = min(max(math.ceil(x0 - 0.5), 0), width)
    r0 = min(max(math.ceil(y0 - 0.5), 0), height)
    c1 = min(max(math.ceil(x1 - 0.5), c0), width)
    r1 = min(max(math.ceil(y1 - 0.5), r0), height)
    return r0, r1, c0, c1
