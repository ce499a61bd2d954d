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
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from PIL import Image
from tqdm import tqdm

from slimseg.deploy.predictor import Predictor
from slimseg.deploy.track_draw import GIF_WIDTH, class_name, draw_tracked, object_masks, paint_order
from slimseg.dynamic.chain_config import ChainConfig, TrackPlan
from slimseg.dynamic.frame_masker import FrameError, FrameMasker
from slimseg.dynamic.masked_frame import MaskedFrame
from slimseg.dynamic.masking_settings import DEFAULT
from slimseg.dynamic.modes import FPS, KEYPOINTS, Mode
from slimseg.dynamic.semantic import objects_of
from slimseg.errors import SlimsegError
from slimseg.objects import SOURCE_DETECTION, Objects
from slimseg.ops.nms_numpy import MAX_DET, NMS_IOU
from slimseg.utils.atomic import atomic_path, staged_dir, write_png, write_text

UNTRACKED_BASE = 60000  # instance-map value of a frame's first untracked detection
GIF_FRAMES = 150  # the GIF holds at most this many frames (~80 KiB each at GIF_WIDTH px)
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
    masks = object_masks(tracked, hw)
    for k in paint_order(tracked):
        imap[masks[k]] = map_ids[k]
    return imap, map_ids


# -- helpers -------------------------------------------------------------------------------


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
               "map_id": int(map_ids[k]), "class": class_name(names, int(tracked.classes[k])),
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
