"""What a prediction is: :class:`Prediction` (one frame's detections, masks or class map, in
source-frame pixels) and :func:`combined_mask` (the SLAM mask of selected classes)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from slimseg.detections import Prediction


def combined_mask(prediction: Prediction, classes: Iterable[int | str] | None = None) -> np.ndarray:
    """``uint8 [h, w]``: 255 where any selected detection is, 0 elsewhere (a SLAM mask).

    ``classes``: class ids or names to keep (``None``: all), e.g. a model's
    ``metadata["dynamic_classes"]``. Detection-only predictions (no masks) fill their boxes;
    semantic predictions mark the pixels of the selected classes in their ``class_map``.
    """
    h, w = prediction.image_hw
    out = np.zeros((h, w), np.uint8)
    if prediction.class_map is not None:
        if classes is None:
            out[prediction.class_map > 0] = 255
            return out
        labels = prediction.class_names
        ids = [
            int(c) + 1 if not isinstance(c, str) else labels.index(c) + 1
            for c in classes
            if not isinstance(c, str) or c in labels
        ]
        out[np.isin(prediction.class_map, ids)] = 255
        return out
    keep = np.ones(len(prediction), bool)
    if classes is not None:
        wanted = set(classes)
        pairs = zip(prediction.classes, prediction.names, strict=True)
        keep = np.array([int(c) in wanted or n in wanted for c, n in pairs], bool).reshape(-1)
    if not keep.any():
        return out
    if prediction.masks is not None:
        out[prediction.masks[keep].any(axis=0)] = 255
        return out
    for x1, y1, x2, y2 in prediction.boxes[keep]:
        # Pixels whose centre lies in the box (the rule masks are cropped with).
        c0, r0 = int(np.ceil(x1 - 0.5)), int(np.ceil(y1 - 0.5))
        c1, r1 = int(np.ceil(x2 - 0.5)), int(np.ceil(y2 - 0.5))
        out[max(r0, 0) : max(r1, 0), max(c0, 0) : max(c1, 0)] = 255
    return out
