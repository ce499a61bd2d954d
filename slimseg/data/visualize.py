"""Drawing samples: masks, boxes and labels over images, tiled into a grid PNG."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from slimseg.data.sample import Sample


def class_color(index: int) -> tuple[int, int, int]:
    """A fixed, well-separated RGB colour per class index (golden-angle hues)."""
    hue = int((index * 137.508) % 180)
    hsv = np.uint8([[[hue, 200, 255]]])
    r, g, b = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0]
    return int(r), int(g), int(b)


def draw_sample(
    sample: Sample, names: Sequence[str] | None = None, alpha: float = 0.45
) -> np.ndarray:
    """RGB ``uint8 [H, W, 3]`` with each instance's mask tinted, its box and class drawn."""
    canvas = sample.image.copy()
    for mask, cls in zip(sample.masks, sample.classes, strict=True):
        color = np.array(class_color(int(cls)), np.float32)
        sel = mask.astype(bool)
        canvas[sel] = (canvas[sel] * (1 - alpha) + color * alpha).astype(np.uint8)
    for box, cls in zip(sample.boxes, sample.classes, strict=True):
        color = class_color(int(cls))
        x1, y1, x2, y2 = (round(float(v)) for v in box)
        cv2.rectangle(canvas, (x1, y1), (x2 - 1, y2 - 1), color, 1)
        label = names[int(cls)] if names and int(cls) < len(names) else str(int(cls))
        cv2.putText(
            canvas,
            label,
            (x1 + 1, max(y1 - 2, 8)),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.3,
            color,
            1,
            cv2.LINE_AA,
        )
    return canvas


def draw_class_map(
    image: np.ndarray,
    class_map: np.ndarray,
    names: Sequence[str] | None = None,
    alpha: float = 0.5,
) -> np.ndarray:
    """RGB ``uint8 [H, W, 3]``: ``image`` tinted with the colour of each pixel's class
    (``class_map [H, W]``, 0 = background left untinted, ``k + 1`` = class ``k``, coloured
    as :func:`draw_sample` colours class ``k``), each present class named at its centroid."""
    canvas = image.copy()
    for label in np.unique(class_map):
        if label == 0:
            continue
        sel = class_map == label
        color = np.array(class_color(int(label) - 1), np.float32)
        canvas[sel] = (canvas[sel] * (1 - alpha) + color * alpha).astype(np.uint8)
        ys, xs = np.nonzero(sel)
        k = int(label) - 1
        text = names[k] if names and k < len(names) else str(k)
        org = (int(xs.mean()), int(ys.mean()))
        cv2.putText(
            canvas, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.3, (255, 255, 255), 1, cv2.LINE_AA
        )
    return canvas


def tile(images: Sequence[np.ndarray], columns: int, gap: int = 2) -> np.ndarray:
    """Tile equally sized RGB images into a grid with a white gap."""
    h, w = images[0].shape[:2]
    rows = (len(images) + columns - 1) // columns
    grid = np.full((rows * (h + gap) - gap, columns * (w + gap) - gap, 3), 255, np.uint8)
    for i, img in enumerate(images):
        r, c = divmod(i, columns)
        grid[r * (h + gap) : r * (h + gap) + h, c * (w + gap) : c * (w + gap) + w] = img
    return grid
