"""How ``slimseg predict --track`` draws a frame's tracks (:func:`draw_tracked`): each track in
a stable colour (untracked detections grey), detected masks filled with a solid outline,
predicted ones hatched with a dashed outline (the look is described in
:mod:`slimseg.deploy.track_predict`)."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import cv2
import numpy as np

from slimseg.data.visualize import class_color
from slimseg.objects import SOURCE_COAST, Objects

GIF_WIDTH = 480  # the animation is downscaled to at most this width: lines scale with it
UNTRACKED_COLOR = (200, 200, 200)
FONT = cv2.FONT_HERSHEY_SIMPLEX


def draw_tracked(
    image: np.ndarray,
    tracked: Objects,
    names: Sequence[str],
    lost: np.ndarray | None = None,
    alpha: float = 0.45,
) -> np.ndarray:
    """RGB ``uint8 [H, W, 3]``: ``image`` (RGB ``uint8 [H, W, 3]``) with the ``M`` objects of
    ``tracked`` drawn in their track's colour (untracked: grey). Detected masks: filled at
    ``alpha``, solid outline and box, label ``#id class score`` above the box. Predicted
    (coasted / carried) masks: diagonal hatching, dashed outline and box, label ``#id class
    lost N`` / ``carried N`` inside the box's bottom, with ``lost int [M]`` frames since the
    track's last detection (None: ``tracked.misses``).
    Lines and text scale with the frame width (the same look once downscaled to GIF_WIDTH)."""
    canvas = image.copy()
    h, w = image.shape[:2]
    scale = max(1.0, w / GIF_WIDTH)
    thick = max(1, round(scale))
    lost = np.asarray(tracked.misses if lost is None else lost)
    masks = object_masks(tracked, (h, w))
    predicted = tracked.predicted
    yy, xx = np.mgrid[:h, :w]
    hatch = ((xx + yy) // max(2, round(3 * scale))) % 2 == 0
    colors = [_color(int(t)) for t in tracked.track_ids]
    order = paint_order(tracked)
    for k in order:
        color = np.array(colors[k], np.float32)
        if predicted[k]:
            for sel, a in ((masks[k] & hatch, 0.8), (masks[k] & ~hatch, 0.15)):
                canvas[sel] = (canvas[sel] * (1 - a) + color * a).astype(np.uint8)
        else:
            sel = masks[k]
            canvas[sel] = (canvas[sel] * (1 - alpha) + color * alpha).astype(np.uint8)
    boxes = []
    for k in order:
        contours, _ = cv2.findContours(
            masks[k].astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE
        )
        x1, y1, x2, y2 = (round(float(v)) for v in tracked.boxes[k])
        x2, y2 = max(x2 - 1, x1), max(y2 - 1, y1)
        boxes.append((k, x1, y1, y2))
        if predicted[k]:
            dash = max(4, round(5 * scale))
            for c in contours:
                _dashed(canvas, c.reshape(-1, 2), colors[k], thick, dash)
            _dashed(canvas, _rect_points(x1, y1, x2, y2), colors[k], thick, dash)
        else:
            cv2.drawContours(canvas, contours, -1, colors[k], thick, cv2.LINE_AA)
            cv2.rectangle(canvas, (x1, y1), (x2, y2), colors[k], thick)
    for k, x1, y1, y2 in boxes:  # labels last, on top of every line
        text = _label_text(tracked, k, names, int(lost[k]))
        _label(canvas, text, (x1, y1, y2), colors[k], bool(predicted[k]), scale)
    return canvas


def object_masks(tracked: Objects, hw: tuple[int, int]) -> np.ndarray:
    """``bool [M, H, W]``: the masks, or the boxes filled for a box-only model."""
    if tracked.masks is not None:
        return np.asarray(tracked.masks, bool)
    masks = np.zeros((len(tracked.boxes), *hw), bool)
    for k, (x1, y1, x2, y2) in enumerate(np.round(tracked.boxes).astype(int)):
        masks[k, max(y1, 0) : max(y2, 0), max(x1, 0) : max(x2, 0)] = True
    return masks


def paint_order(tracked: Objects) -> list[int]:
    """Predicted masks first (most misses first), then detections by ascending score."""
    coasted = tracked.predicted
    keys = [
        (0, -int(tracked.misses[k])) if coasted[k] else (1, float(tracked.scores[k]))
        for k in range(len(tracked.boxes))
    ]
    return sorted(range(len(keys)), key=lambda k: keys[k])


def _color(track_id: int) -> tuple[int, int, int]:
    return UNTRACKED_COLOR if track_id < 0 else class_color(track_id)


def class_name(names: Sequence[str], cls: int) -> str:
    """The name of class ``cls`` (its number where ``names`` has none)."""
    return names[cls] if 0 <= cls < len(names) else str(cls)


def _label_text(tracked: Objects, k: int, names: Sequence[str], lost: int) -> str:
    tid = int(tracked.track_ids[k])
    head = (f"#{tid} " if tid >= 0 else "") + class_name(names, int(tracked.classes[k]))
    if not tracked.predicted[k]:
        return f"{head} {float(tracked.scores[k]):.2f}"
    return f"{head} {'lost' if tracked.source[k] == SOURCE_COAST else 'carried'} {lost}"


def _label(canvas, text, xyy, color, predicted: bool, scale: float) -> None:
    """``text`` at box ``xyy`` = (x1, y1, y2): above its top in a colour box with black text
    (detected), inside its bottom in a black box with coloured text (predicted)."""
    font, thick = 0.4 * scale, max(1, round(scale))
    (tw, th), base = cv2.getTextSize(text, FONT, font, thick)
    x = min(max(xyy[0], 0), max(canvas.shape[1] - tw - 2, 0))
    y = min(xyy[2], canvas.shape[0] - 1) if predicted else xyy[1]
    y = max(y, th + base + 2)
    back, ink = ((0, 0, 0), color) if predicted else (color, (0, 0, 0))
    cv2.rectangle(canvas, (x, y - th - base - 2), (x + tw + 2, y), back, -1)
    cv2.putText(canvas, text, (x + 1, y - base), FONT, font, ink, thick, cv2.LINE_AA)


def _dashed(canvas: np.ndarray, pts: np.ndarray, color, thick: int, dash: int) -> None:
    """A closed dashed line through dense points ``pts int [N, 2]`` (x, y)."""
    if len(pts) < 2:
        return
    loop = np.vstack([pts, pts[:1]]).astype(np.int32)
    step = np.hypot(*np.diff(loop, axis=0).T.astype(np.float64))
    on = (np.concatenate([[0.0], np.cumsum(step)]) // dash) % 2 == 0
    cuts = np.flatnonzero(np.diff(on.astype(np.int8))) + 1
    runs = [loop[r] for r in np.split(np.arange(len(loop)), cuts) if on[r[0]] and len(r) > 1]
    if runs:
        cv2.polylines(canvas, runs, False, color, thick, cv2.LINE_AA)


def _rect_points(x1: int, y1: int, x2: int, y2: int) -> np.ndarray:
    """``int [N, 2]``: the rectangle's outline, one point per pixel step."""
    corners = [(x1, y1), (x2, y1), (x2, y2), (x1, y2), (x1, y1)]
    parts = [
        np.linspace(a, b, max(abs(b[0] - a[0]), abs(b[1] - a[1]), 1), endpoint=False)
        for a, b in itertools.pairwise(corners)
    ]
    return np.round(np.concatenate(parts)).astype(np.int32)
