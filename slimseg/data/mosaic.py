"""Four-image mosaic: four samples tiled around a random centre, cropped to the output size."""

from __future__ import annotations

import cv2
import numpy as np

from slimseg.data.sample import Sample
from slimseg.ops.letterbox import PAD_VALUE


def mosaic4(samples: list[Sample], size: int, rng: np.random.Generator) -> Sample:
    """Tile four samples into one ``size × size`` sample.

    Each sample is resized so its longer side is ``size`` and placed in one quadrant of a
    virtual ``2·size`` canvas, meeting at a random centre in ``[0.5, 1.5]·size``; the output is
    the canvas' central ``size × size`` window (only that window is ever allocated).
    Masks keep only their visible part inside the window; boxes are left to the caller
    (recomputed from masks after the remaining augmentation).
    """
    if len(samples) != 4:
        raise ValueError(f"mosaic4 needs 4 samples, got {len(samples)}")
    s = size
    xc, yc = (int(v) for v in rng.uniform(0.5 * s, 1.5 * s, 2))
    origin = s // 2  # window [origin, origin + s) on both axes of the 2s canvas
    image = np.full((s, s, 3), PAD_VALUE, np.uint8)
    pieces, classes = [], []  # (crop, window rows, window cols) of each visible mask
    for k, smp in enumerate(samples):
        h0, w0 = smp.image.shape[:2]
        r = s / max(h0, w0)
        w, h = max(1, round(w0 * r)), max(1, round(h0 * r))
        img = cv2.resize(smp.image, (w, h), interpolation=cv2.INTER_LINEAR) if r != 1 else smp.image
        # top-left of this tile on the canvas: quadrants TL, TR, BL, BR around (xc, yc)
        x0 = xc - w if k in (0, 2) else xc
        y0 = yc - h if k in (0, 1) else yc
        # intersection of the tile with the window, in window coordinates
        wx1, wy1 = max(x0 - origin, 0), max(y0 - origin, 0)
        wx2, wy2 = min(x0 + w - origin, s), min(y0 + h - origin, s)
        if wx2 <= wx1 or wy2 <= wy1:
            continue
        tx1, ty1 = wx1 - (x0 - origin), wy1 - (y0 - origin)
        tx2, ty2 = tx1 + (wx2 - wx1), ty1 + (wy2 - wy1)
        image[wy1:wy2, wx1:wx2] = img[ty1:ty2, tx1:tx2]
        for m, c in zip(smp.masks, smp.classes, strict=True):
            mm = cv2.resize(m, (w, h), interpolation=cv2.INTER_NEAREST_EXACT) if r != 1 else m
            crop = mm[ty1:ty2, tx1:tx2]
            if not crop.any():
                continue
            pieces.append((crop, slice(wy1, wy2), slice(wx1, wx2)))
            classes.append(c)
    mask_arr = np.zeros((len(pieces), s, s), np.uint8)  # one allocation, no stacking copy
    for k, (crop, rows, cols) in enumerate(pieces):
        mask_arr[k, rows, cols] = crop
    return Sample(
        image=image,
        boxes=np.zeros((len(classes), 4), np.float32),
        classes=np.asarray(classes, np.int64).reshape(-1),
        masks=mask_arr,
        image_id=samples[0].image_id,
        path=samples[0].path,
        meta={"mosaic": [smp.path for smp in samples]},
    )
