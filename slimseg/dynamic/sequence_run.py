"""Run the reference masking logic over a TUM RGB-D sequence, optionally scoring it.

Per frame, :class:`~slimseg.dynamic.frame_masker.FrameMasker` (model → detections in frame
pixels → ORB keypoints → track stage → the chosen mode) → ``masks/<rgb timestamp>.png``
(uint8, 255 = dynamic; the offline mask-cache convention of DynaSLAM-style runtimes) and a
CSV row. When the sequence has ground-truth
``dynamic/`` masks (the synthetic generator writes them), every mode is scored on the same
detections and keypoints: precision and recall of dynamic keypoints.

The epipolar modes get the previous frame's ORB features (``PreviousFrame``); the first frame
has none and behaves like the base mode. ``predictor`` may also be an
:class:`~slimseg.dynamic.annotations.AnnotationInstances` (ground-truth instances of a synthetic
sequence): then the report also counts how the epipolar check classified every checked
instance against its ground-truth ``moving`` flag.
"""

from __future__ import annotations

import csv
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from slimseg.data.images import decode_file
from slimseg.data.sequence_source import Sequence, open_sequence
from slimseg.data.tum import mask_name
from slimseg.data.visualize import tile
from slimseg.dynamic.annotations import AnnotationInstances
from slimseg.dynamic.frame_masker import FrameMasker, segmenter_for
from slimseg.dynamic.masking_settings import DEFAULT, MaskingSettings
from slimseg.dynamic.pipeline import EPIPOLAR_MODES, MODES, FrameResult
from slimseg.dynamic.recall_loss import RecallLoss
from slimseg.dynamic.track_run import TRACK_OFF, TrackPlan
from slimseg.dynamic.track_types import TrackedFrame
from slimseg.utils.atomic import write_png


@dataclass
class ModeScore:
    """Keypoint-level confusion counts of one mode against ground-truth dynamic masks."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0

    def add(self, dynamic: np.ndarray, truth: np.ndarray) -> None:
        """Count one frame: predicted ``dynamic [N]`` vs ground-truth ``truth [N]`` (bool)."""
        self.tp += int((dynamic & truth).sum())
        self.fp += int((dynamic & ~truth).sum())
        self.fn += int((~dynamic & truth).sum())
        self.tn += int((~dynamic & ~truth).sum())

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else float("nan")

    @property
    def recall(self) -> float:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else float("nan")


@dataclass
class SequenceReport:
    frames: int = 0
    skipped: list[str] = field(default_factory=list)
    scores: dict[str, ModeScore] = field(default_factory=dict)
    ms_per_frame: dict[str, float] = field(default_factory=dict)
    epipolar: dict[str, int] = field(default_factory=dict)
    """GT instances only: ``"<truth> as <decision>"`` counts, truth moving/static, decision
    moving/static/undecided, over every instance the epipolar check looked at."""
    recall_loss: RecallLoss | None = None
    """the chosen mode's missed keypoints split by dropout vs partial cover, ghosts
    (sequences with ``annotations.json`` and ``dynamic/``)"""
    model_frames: int = 0
    """frames the model ran on (``--segment-every``: about frames / N)"""
    coasted: int = 0
    """predicted masks the track stage emitted (coasted or carried)"""
    latency_ms: list[float] = field(default_factory=list)
    """per frame: from when the loop takes it up (at its arrival in a real-time replay, or
    later when the loop is behind) to its mask being ready (the chosen mode; before the
    scoring of the others and the writing): what a SLAM front end waits per frame"""
    late_ms: list[float] = field(default_factory=list)
    """real-time replay: per frame, how long after its arrival the loop took it up (the
    replay's own reading, scoring and writing count here; a runtime has none of them)"""
    model_lags: list[int] = field(default_factory=list)
    """per model result used: frames between the frame it was computed on and the one it fed"""
    model_ms_per_run: float = 0.0
    """mean wall time of one model run (on whichever thread)"""
    stage_parts_ms: dict[str, float] = field(default_factory=dict)
    """the track stage's time per frame by part (``slimseg.dynamic.track.STAGE_PARTS``)"""
    rate: str = ""
    """how the model's rate was set (``ModelFeed.describe``)"""
    gave_up: int = 0
    """frames the chosen mode's rule masked nothing while objects were candidates (Eq. 1
    giving up the frame)"""
    dropped: int = 0
    """candidate objects the rule left out of the mask, over the sequence"""
    dropped_confident_frames: int = 0
    """frames in which the rule left out a candidate scoring at least ``keep_score``"""


def sequence_masker(
    predictor: object,
    seq: Sequence,
    mode: str = "fusion",
    masking: MaskingSettings = DEFAULT,
    keypoints: int = 1000,
    epipolar_depth: bool = False,
    track: TrackPlan = TRACK_OFF,
) -> FrameMasker:
    """The chain ``slimseg dynamic`` runs over ``seq``: ``predictor`` (a slimseg ``Predictor``
    or ``AnnotationInstances``) at the ``track`` plan's rate; with ground-truth ``dynamic/``
    masks every other mode is scored on the same inputs (ground-truth instances: the epipolar
    check too, for its tally)."""
    score = MODES if (seq.root / "dynamic").is_dir() else ()
    if isinstance(predictor, AnnotationInstances) and "semantic+epipolar" not in score:
        score = (*score, "semantic+epipolar")
    cam = seq.camera
    return FrameMasker(
        segmenter_for(predictor), class_mobility=predictor.mobility, mode=mode,
        masking=masking, track=track.settings, rate=track.rate, keypoints=keypoints,
        camera=(cam.fx, cam.fy, cam.cx, cam.cy) if epipolar_depth else None, fps=seq.fps,
        score_modes=score,
    )  # fmt: skip


def run_sequence(
    predictor: object,
    sequence: Path | Sequence,
    out: Path,
    mode: str = "fusion",
    masking: MaskingSettings = DEFAULT,
    keypoints: int = 1000,
    progress: bool = True,
    epipolar_depth: bool = False,
    track: TrackPlan = TRACK_OFF,
    fps: float | None = None,
) -> SequenceReport:
    """Process every associated frame of ``sequence`` with ``predictor`` (a slimseg
    ``Predictor`` or ``AnnotationInstances``) under the ``masking`` settings (score threshold,
    dilation, Eq. 1/3/4); write masks, ``frames.csv`` and ``overlay.png`` under ``out``.
    ``epipolar_depth``: give the epipolar check the previous depth and the intrinsics
    (depth-aided residual, see ``epipolar``). ``sequence``: the folder, or it opened.
    ``track``: the track stage and the model's rate (off by default: every frame judged
    alone); with it on, ``tracks.csv`` lists every emitted object with its track id and
    source. With the model on its own thread the frames are replayed in real time at ``fps``
    (None: the sequence's own timestamps; 0: as fast as the loop goes). A loop over
    :class:`~slimseg.dynamic.frame_masker.FrameMasker` (:func:`sequence_masker`)."""
    seq = open_sequence(sequence) if isinstance(sequence, str | Path) else sequence
    with sequence_masker(predictor, seq, mode, masking, keypoints, epipolar_depth, track) as m:
        gt = predictor if isinstance(predictor, AnnotationInstances) else None
        return _loop(m, seq, out, gt, progress, fps)


def _loop(
    masker: FrameMasker,
    seq: Sequence,
    out: Path,
    gt_instances: AnnotationInstances | None,
    progress: bool,
    fps: float | None,
) -> SequenceReport:
    gt_dir = seq.root / "dynamic"
    mode = masker.mode
    (out / "masks").mkdir(parents=True, exist_ok=True)
    report = SequenceReport(scores={m: ModeScore() for m in MODES} if gt_dir.is_dir() else {})
    report.rate = masker.rate.describe()
    rows, panels, track_rows, stamps = [], [], [], []
    t_model = t_logic = 0.0
    step = max(len(seq.frames) // 6, 1)
    losses = RecallLoss() if gt_dir.is_dir() and (seq.root / "annotations.json").is_file() else None
    instances = _instances(gt_instances, seq.root) if losses is not None else None
    live = masker.rate.thread  # frames replayed in real time
    clock = _Replay(fps if live else 0.0, masker.clock)
    keep = masker.masking.keep_score
    for i in tqdm(range(len(seq.frames)), desc="dynamic", disable=not progress):
        rgb, depth, stamp = seq.load(i)
        arrival = clock.arrive(i, stamp)
        taken = masker.clock()
        f = masker.step(rgb, depth, stamp)
        report.model_frames += f.model_ran
        report.latency_ms.append(f.timing.latency)
        if live:
            report.late_ms.append(1000 * max(taken - arrival, 0.0))
        t_logic += f.timing.masking / 1000  # the chosen mode only, not the scoring of the rest
        t_model += f.timing.model / 1000  # the loop's time in the model (inline), or waiting
        result, tracked, kps, hw = f.result, f.tracked, f.keypoints, f.mask.shape
        masks = f.objects.masks
        if tracked is not None:
            report.coasted += int(tracked.coasted.sum())
            track_rows += _track_rows(stamp, tracked)
        name = mask_name(stamp)
        write_png(out / "masks" / name, result.mask)
        confident = _confident(result.dropped, f.inputs.scores, keep)
        report.gave_up += result.m_th is None and bool(result.dropped)
        report.dropped += len(result.dropped)
        report.dropped_confident_frames += confident > 0
        rows.append(
            {
                "timestamp": f"{stamp:.6f}",
                **result.counts,
                "m_th": result.m_th,
                "support": result.support,
                "dropped": len(result.dropped),
                "dropped_confident": confident,
                "dynamic_frame": result.dynamic_frame,
                "used_seg": result.used_seg,
                "detections": len(f.objects),
                "model_ms": round(f.timing.model, 2),
                **({} if tracked is None else {"coasted": int(tracked.coasted.sum())}),
            }
        )
        if report.scores:
            gt = decode_file(gt_dir / name, cv2.IMREAD_GRAYSCALE)
            if gt is None:
                report.skipped.append(str(gt_dir / name))
            else:
                truth = at_keypoints(gt > 0, kps)
                for m, res in f.results.items():
                    report.scores[m].add(res.dynamic, truth)
                if losses is not None:
                    only = _coasted_only(tracked, masks, hw)
                    losses.add(instances, stamp, kps, result.dynamic, truth, result.mask > 0, only)
        epi_mode = mode if mode in EPIPOLAR_MODES else "semantic+epipolar"
        stamps.append(stamp)
        if gt_instances is not None and i > 0 and epi_mode in f.results:
            # the detections' own frame (a late result's is older than this one)
            seen = stamps[i - f.lag] if f.model_ran else stamp
            _count_epipolar(report, gt_instances, seen, f.results[epi_mode], tracked)
        if i % step == 0 and len(panels) < 6:
            ghost = None if tracked is None else _coasted_only(tracked, masks, hw)
            panels.append(_overlay(rgb, result.mask, kps, result.dynamic, ghost))
        report.frames += 1
    _write_csv(out / "frames.csv", rows)
    stage, feed = masker.stage, masker.feed
    if stage is not None:
        _write_csv(out / "tracks.csv", track_rows)
    if losses is not None:
        report.recall_loss = losses.finish()
    if panels:
        write_png(out / "overlay.png", tile(panels, 3))
    n = max(report.frames, 1)
    report.ms_per_frame = {"model": 1000 * t_model / n, "masking_logic": 1000 * t_logic / n}
    if stage is not None:  # its time is inside masking_logic (preparation); shown apart too
        report.ms_per_frame["track_stage"] = stage.ms_per_frame
        report.stage_parts_ms = {k: 1000 * v / n for k, v in stage.tracker.parts.items()}
    report.model_lags = list(feed.lags)
    report.model_ms_per_run = 1000 * feed.model_s / max(feed.model_runs, 1)
    if live:  # the loop waited for the model only on the first frame: count its runs' time
        report.ms_per_frame["model_thread"] = 1000 * feed.model_s / n
    return report


def _confident(dropped: list[int], scores: np.ndarray | None, keep_score: float) -> int:
    """How many of the ``dropped`` objects scored at least ``keep_score`` (no scores: all)."""
    if scores is None:
        return len(dropped)
    return int((np.asarray(scores)[np.asarray(dropped, int)] >= keep_score).sum())


class _Replay:
    """Frame arrival times: the sequence's timestamps (``fps`` None) or ``i / fps`` from the
    first frame, in real time on ``clock`` (the masker's: scoring pauses it); ``fps`` 0: each
    frame arrives when the loop asks for it."""

    def __init__(self, fps: float | None, clock: Callable[[], float]) -> None:
        self.fps = fps
        self.clock = clock
        self.first: tuple[float, float] | None = None  # (clock, stamp) of frame 0

    def arrive(self, i: int, stamp: float) -> float:
        """Wait until frame ``i`` arrives; return its arrival time (on ``clock``, s)."""
        now = self.clock()
        if self.fps == 0:
            return now
        if self.first is None:
            self.first = (now, stamp)
            return now
        c0, s0 = self.first
        due = c0 + (stamp - s0 if self.fps is None else i / self.fps)
        if due > now:
            time.sleep(due - now)
        return due


def _instances(gt: AnnotationInstances | None, root: Path) -> AnnotationInstances:
    """The sequence's complete ground-truth instances (never a dropout-injected copy)."""
    if gt is not None and gt.dropout is None:
        return gt
    return AnnotationInstances(root)


def _coasted_only(
    tracked: TrackedFrame | None, masks: np.ndarray | None, hw: tuple[int, int]
) -> np.ndarray | None:
    """``bool [H, W]``: pixels of coasted masks that no detection mask covers."""
    if tracked is None or masks is None or not tracked.coasted.any():
        return None if tracked is None else np.zeros(hw, bool)
    det = masks[~tracked.coasted].any(0) if (~tracked.coasted).any() else np.zeros(hw, bool)
    return masks[tracked.coasted].any(0) & ~det


def _track_rows(stamp: float, tracked: TrackedFrame) -> list[dict]:
    return [
        {
            "timestamp": f"{stamp:.6f}",
            "track_id": int(tracked.track_ids[k]),
            "class": int(tracked.classes[k]),
            "source": tracked.source[k],
            "misses": int(tracked.misses[k]),
            "mobility": round(float(tracked.mobility[k]), 4),
            "score": round(float(tracked.scores[k]), 4),
            "box": " ".join(f"{v:.1f}" for v in tracked.boxes[k]),
        }
        for k in range(len(tracked.boxes))
    ]


def _count_epipolar(
    report: SequenceReport,
    instances: AnnotationInstances,
    stamp: float,
    result: FrameResult,
    tracked: TrackedFrame | None = None,
) -> None:
    """Tally an epipolar mode's decisions on this frame's instances against their ``moving``
    flag (``result``: that mode's outcome, with the check it ran; ``tracked``: the track
    stage's objects, whose predicted masks are not instances and are left out)."""
    epi = result.epipolar
    if epi is None:
        return
    checked = np.asarray(result.checked, int)
    if tracked is not None:
        checked = tracked.det_index[checked]
    keep = checked >= 0
    truth = instances.moving(stamp)[checked[keep]]
    for t, dec, mov in zip(truth, epi.decided[keep], epi.moving[keep], strict=True):
        decision = "moving" if mov else ("static" if dec else "undecided")
        key = f"{'moving' if t else 'static'} as {decision}"
        report.epipolar[key] = report.epipolar.get(key, 0) + 1


def at_keypoints(mask: np.ndarray, kps: np.ndarray) -> np.ndarray:
    """``mask [H, W]`` sampled at ``kps [N, 2]`` (x, y) px, rounded and clipped → ``[N]``."""
    h, w = mask.shape
    x = np.clip(np.round(kps[:, 0]).astype(int), 0, w - 1)
    y = np.clip(np.round(kps[:, 1]).astype(int), 0, h - 1)
    return mask[y, x]


def _overlay(
    rgb: np.ndarray,
    mask: np.ndarray,
    kps: np.ndarray,
    dyn: np.ndarray,
    coasted: np.ndarray | None = None,
) -> np.ndarray:
    """Red: the dynamic mask; yellow: its part that only coasted masks cover."""
    out = rgb.copy()
    sel = mask > 0
    out[sel] = (0.5 * out[sel] + 0.5 * np.array([255, 0, 0])).astype(np.uint8)
    if coasted is not None:
        c = coasted & sel
        out[c] = (0.4 * rgb[c] + 0.6 * np.array([255, 220, 0])).astype(np.uint8)
    for (x, y), d in zip(kps.astype(int), dyn, strict=True):
        cv2.circle(out, (int(x), int(y)), 2, (255, 0, 0) if d else (0, 255, 0), -1)
    return out


def _write_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        return
    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, path)
