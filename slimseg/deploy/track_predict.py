"""``slimseg predict --track``: a folder of frames or a video → tracks, instance maps, a CSV and
an animation.

Per frame the chain (:class:`~slimseg.dynamic.frame_masker.FrameMasker` in mode ``seg``: no
epipolar check, no depth gate) runs the model at the track stage's low threshold (with
``--rate N`` on frames 0, N, 2N, ... only) and its stage matches the detections to
the tracks. It emits every detection scoring above
``conf`` and, besides, the predicted masks of tracks the model just lost (``coast``) or did not
run on (``carried``). Classes whose mobility prior is at most the masking threshold
(``m_th_start`` of the ``slimseg`` masking preset) are not tracked: they pass through as
untracked detections (people and pets are tracked, furniture is not).

Outputs under ``out``, written into a temporary folder beside it and moved into place when the
last frame is done (a run that fails midway leaves ``out`` as it was):

- ``tracks/<stem>.png``: ``uint16 [H, W]`` instance map. 0 = background, ``1 ..
  UNTRACKED_BASE - 1`` = the track id, ``UNTRACKED_BASE + k`` = the frame's k-th untracked
  detection (not stable across frames). Where masks overlap, detections cover predicted masks
  and a higher score covers a lower one. Box-only models fill their boxes.
- ``tracks.csv``: one row per emitted object: ``frame`` (0-based), ``stem``, ``track_id``
  (-1: untracked), ``map_id`` (its value in the instance map), ``class`` (name), ``source``
  (det / coast / carried), ``misses`` (model frames since the track's last detection),
  ``score`` (empty for predicted masks), ``x1 y1 x2 y2`` (box, frame pixels).
- ``tracks.gif`` (at most ``GIF_WIDTH`` px wide, the first ``GIF_FRAMES`` frames) and
  ``tracks.mp4`` (full size, every frame, when OpenCV can write mp4v): each track in a stable
  colour (untracked detections grey); detected masks filled translucent with a solid outline,
  labelled ``#id class score`` above the box; predicted masks hatched with a dashed outline
  and box, labelled ``#id class lost N`` (coasted) or ``#id class carried N`` (N = frames
  since the last detection) inside the box's bottom.
"""

from __future__ import annotations

import csv
import io
import itertools
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from PIL import Image
from tqdm import tqdm

from slimseg.data.visualize import class_color
from slimseg.deploy.predictor import Predictor
from slimseg.dynamic.chain_config import ChainConfig, TrackPlan
from slimseg.dynamic.frame_masker import FrameError, FrameMasker, MaskedFrame
from slimseg.dynamic.masking_settings import DEFAULT
from slimseg.dynamic.modes import FPS, KEYPOINTS, Mode
from slimseg.dynamic.semantic import objects_of
from slimseg.errors import SlimsegError
from slimseg.objects import SOURCE_COAST, SOURCE_DETECTION, Objects
from slimseg.ops.nms_numpy import MAX_DET, NMS_IOU
from slimseg.utils.atomic import atomic_path, staged_dir, write_png, write_text

UNTRACKED_BASE = 60000  # instance-map value of a frame's first untracked detection
GIF_WIDTH = 480  # the GIF is downscaled to at most this width ...
GIF_FRAMES = 150  # ... and holds at most this many frames (~80 KiB each at 480 px)
UNTRACKED_COLOR = (200, 200, 200)
CSV_FIELDS = (
    "frame",
    "stem",
    "track_id",
    "map_id",
    "class",
    "source",
    "misses",
    "score",
    "x1",
    "y1",
    "x2",
    "y2",
)
FONT = cv2.FONT_HERSHEY_SIMPLEX

Frame = tuple[str, str, np.ndarray | None]
"""``(stem, source path, RGB uint8 [H, W, 3] or None if unreadable)``"""


@dataclass
class TrackReport:
    """What a tracked run did; ``model_s`` / ``track_s``: seconds in the model and in the track
    stage (ORB features, camera motion, association, coasting)."""

    frames: int = 0
    model_frames: int = 0
    tracks: int = 0
    predicted: int = 0
    """predicted masks emitted (coasted or carried)"""
    model_s: float = 0.0
    track_s: float = 0.0
    skipped: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def ms_per_frame(self) -> float:
        """Mean model + track-stage time per frame (drawing and writing left out)."""
        return 1000 * (self.model_s + self.track_s) / max(self.frames, 1)

    def summary(self) -> str:
        n = max(self.frames, 1)
        return (
            f"{self.frames} frame(s) (model on {self.model_frames}), {self.tracks} track(s), "
            f"{self.predicted} predicted mask(s) emitted; {self.ms_per_frame:.1f} ms/frame "
            f"(model {1000 * self.model_s / n:.1f} + track stage {1000 * self.track_s / n:.1f})"
            f" -> {', '.join(self.files) or 'nothing written'}"
        )


def track_predict(
    predictor: Predictor,
    frames: Iterable[Frame],
    out: Path,
    plan: TrackPlan,
    conf: float,
    iou: float = NMS_IOU,
    max_det: int = MAX_DET,
    fps: float = FPS,
    total: int = 0,
    progress: bool = True,
    keypoints: int = KEYPOINTS,
    observers: Sequence[Callable[[MaskedFrame, np.ndarray, None], None]] = (),
) -> TrackReport:
    """Track ``frames`` (in order; ``total``: their count for the progress bar, 0 unknown) with
    ``predictor`` under ``plan`` (must be on); ``conf``: the score above which a detection is
    emitted. Writes the files of the module docstring under ``out``; ``observers``: called
    with every frame's outcome and colour image."""
    if not plan.on:
        raise ValueError("track_predict needs a TrackPlan with settings (the stage on)")
    out = Path(out)

    def segment(rgb: np.ndarray, stamp: float, floor: float) -> Objects:
        pred = predictor.predict(rgb, conf=floor, iou=iou, max_det=max_det)
        return objects_of(pred, rgb.shape[:2])

    config = ChainConfig(mode=Mode.SEG, masking=DEFAULT.with_values(conf=conf), track=plan,
                         keypoints=keypoints, fps=fps)  # fmt: skip
    masker = FrameMasker(segment, predictor.mobility, config)
    names = list(predictor.names)
    report, rows, ids = TrackReport(), [], set()
    last_det: dict[int, int] = {}  # track id -> last frame it was detected in
    hw: tuple[int, int] | None = None
    gif: list[Image.Image] = []
    with staged_dir(out, command="predict --track") as folder, masker:  # complete or not at all
        video = _Video(folder / "tracks.mp4", fps)
        try:
            for stem, source, rgb in tqdm(
                frames, total=total or None, desc="track", unit="frame", disable=not progress
            ):
                if rgb is None:
                    report.skipped.append(source)
                    continue
                i = report.frames
                try:
                    f = masker.step(rgb)
                except FrameError as e:
                    raise SlimsegError(f"{source}: {e}") from None
                for observe in observers:  # a Rerun recording (no depth here)
                    observe(f, rgb, None)
                hw = f.mask.shape
                tracked = f.objects
                report.model_frames += f.model_ran
                report.model_s += f.timing.model / 1000
                report.track_s += (f.timing.features + f.timing.track) / 1000
                report.frames += 1

                tids = tracked.track_ids
                for k, tid in enumerate(tids):
                    if tid >= 0 and tracked.source[k] == SOURCE_DETECTION:
                        last_det[int(tid)] = i
                lost = np.array([i - last_det.get(int(t), i) for t in tids], np.int64)
                imap, map_ids = instance_map(tracked, hw)
                write_png(folder / "tracks" / f"{stem}.png", imap)
                rows += _rows(i, stem, tracked, map_ids, names)
                ids.update(int(t) for t in tids if t >= 0)
                report.predicted += int(tracked.predicted.sum())
                drawn = draw_tracked(rgb, tracked, names, lost)
                video.add(drawn)
                if len(gif) < GIF_FRAMES:
                    gif.append(_gif_frame(drawn))
            report.tracks = len(ids)
            if report.frames:
                report.files.append(str(out / "tracks") + "/")
                write_text(folder / "tracks.csv", _csv(rows))
                report.files.append(str(out / "tracks.csv"))
                with atomic_path(folder / "tracks.gif") as tmp:
                    gif[0].save(tmp, format="GIF", save_all=True, append_images=gif[1:], loop=0,
                                duration=max(20, round(1000 / fps)))  # fmt: skip
                report.files.append(str(out / "tracks.gif"))
                if report.frames > GIF_FRAMES:
                    report.notes.append(
                        f"tracks.gif holds the first {GIF_FRAMES} of {report.frames} frames"
                        + (" (tracks.mp4 has them all)" if video.ok else "")
                    )
                if video.finish():
                    report.files.append(str(out / "tracks.mp4"))
                else:
                    report.notes.append("tracks.mp4 not written: OpenCV cannot write mp4v here")
        finally:
            video.close()
    return report


def instance_map(tracked: Objects, hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``(uint16 [H, W] instance map, map_ids int64 [M])`` of one frame's ``M`` objects (see
    the module docstring for the values and which object wins an overlapping pixel)."""
    tids = np.asarray(tracked.track_ids, np.int64)
    if len(tids) and tids.max() >= UNTRACKED_BASE:
        raise SlimsegError(
            f"track id {tids.max()} does not fit the uint16 instance map "
            f"(track ids must stay below {UNTRACKED_BASE})"
        )
    untracked = tids < 0
    map_ids = tids.copy()
    map_ids[untracked] = UNTRACKED_BASE + np.arange(int(untracked.sum()))
    imap = np.zeros(hw, np.uint16)
    masks = _object_masks(tracked, hw)
    for k in _paint_order(tracked):
        imap[masks[k]] = map_ids[k]
    return imap, map_ids


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
    masks = _object_masks(tracked, (h, w))
    predicted = tracked.predicted
    yy, xx = np.mgrid[:h, :w]
    hatch = ((xx + yy) // max(2, round(3 * scale))) % 2 == 0
    colors = [_color(int(t)) for t in tracked.track_ids]
    order = _paint_order(tracked)
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


# -- helpers -------------------------------------------------------------------------------


def _object_masks(tracked: Objects, hw: tuple[int, int]) -> np.ndarray:
    """``bool [M, H, W]``: the masks, or the boxes filled for a box-only model."""
    if tracked.masks is not None:
        return np.asarray(tracked.masks, bool)
    masks = np.zeros((len(tracked.boxes), *hw), bool)
    for k, (x1, y1, x2, y2) in enumerate(np.round(tracked.boxes).astype(int)):
        masks[k, max(y1, 0) : max(y2, 0), max(x1, 0) : max(x2, 0)] = True
    return masks


def _paint_order(tracked: Objects) -> list[int]:
    """Predicted masks first (most misses first), then detections by ascending score."""
    coasted = tracked.predicted
    keys = [
        (0, -int(tracked.misses[k])) if coasted[k] else (1, float(tracked.scores[k]))
        for k in range(len(tracked.boxes))
    ]
    return sorted(range(len(keys)), key=lambda k: keys[k])


def _color(track_id: int) -> tuple[int, int, int]:
    return UNTRACKED_COLOR if track_id < 0 else class_color(track_id)


def _name(names: Sequence[str], cls: int) -> str:
    return names[cls] if 0 <= cls < len(names) else str(cls)


def _label_text(tracked: Objects, k: int, names: Sequence[str], lost: int) -> str:
    tid = int(tracked.track_ids[k])
    head = (f"#{tid} " if tid >= 0 else "") + _name(names, int(tracked.classes[k]))
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


def _gif_frame(rgb: np.ndarray) -> Image.Image:
    """A palette image at most ``GIF_WIDTH`` px wide."""
    h, w = rgb.shape[:2]
    if w > GIF_WIDTH:
        rgb = cv2.resize(
            rgb, (GIF_WIDTH, max(1, round(h * GIF_WIDTH / w))), interpolation=cv2.INTER_AREA
        )
    return Image.fromarray(rgb).quantize(colors=255, method=Image.Quantize.FASTOCTREE)


def _rows(i: int, stem: str, tracked: Objects, map_ids: np.ndarray, names) -> list[dict]:
    rows, coasted = [], tracked.predicted
    for k in range(len(tracked.boxes)):
        row = {"frame": i, "stem": stem, "track_id": int(tracked.track_ids[k]),
               "map_id": int(map_ids[k]), "class": _name(names, int(tracked.classes[k])),
               "source": tracked.source[k], "misses": int(tracked.misses[k]),
               "score": "" if coasted[k] else round(float(tracked.scores[k]), 4)}  # fmt: skip
        for c, v in zip(CSV_FIELDS[-4:], tracked.boxes[k], strict=True):
            row[c] = round(float(v), 1)
        rows.append(row)
    return rows


def _csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_FIELDS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


class _Video:
    """``tracks.mp4`` (mp4v) written to a temporary name; :meth:`finish` renames it."""

    def __init__(self, path: Path, fps: float) -> None:
        self.path, self.fps = path, fps
        self.tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
        self.writer: cv2.VideoWriter | None = None
        self.ok = True

    def add(self, rgb: np.ndarray) -> None:
        if not self.ok:
            return
        if self.writer is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fourcc = cv2.VideoWriter_fourcc(*"mp4v")
            size = (rgb.shape[1], rgb.shape[0])
            self.writer = cv2.VideoWriter(str(self.tmp), fourcc, self.fps, size)
            self.ok = self.writer.isOpened()
            if not self.ok:
                return
        self.writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))

    def finish(self) -> bool:
        """Close the file and move it into place; False if it could not be written."""
        self.close(keep=True)
        if self.ok and self.tmp.is_file():
            os.replace(self.tmp, self.path)
            return True
        return False

    def close(self, keep: bool = False) -> None:
        if self.writer is not None:
            self.writer.release()
        if not keep:
            self.tmp.unlink(missing_ok=True)
