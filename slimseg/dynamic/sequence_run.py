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

import time
from collections.abc import Callable
from collections.abc import Sequence as Sequence_
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from slimseg.data.frame_source import FrameSource
from slimseg.data.images import decode_file
from slimseg.data.sequence_source import opens_sequence
from slimseg.data.tum import mask_name
from slimseg.data.visualize import tile
from slimseg.dynamic.annotations import AnnotationInstances
from slimseg.dynamic.frame_masker import FrameMasker, MaskedFrame, segmenter_for
from slimseg.dynamic.masking_settings import DEFAULT, MaskingSettings
from slimseg.dynamic.model_feed import RecordedFeed
from slimseg.dynamic.packed_detections import PackedDetections
from slimseg.dynamic.pipeline import EPIPOLAR_MODES, MODES, FrameResult
from slimseg.dynamic.recall_loss import RecallLoss
from slimseg.dynamic.sequence_report import (
    ModeScore,
    SequenceReport,
    at_keypoints,
    coasted_only,
    overlay,
    track_rows,
    write_csv,
)
from slimseg.dynamic.track_run import TRACK_OFF, TrackPlan
from slimseg.dynamic.track_types import TrackedFrame
from slimseg.utils.atomic import write_png

Observer = Callable[[MaskedFrame, np.ndarray, np.ndarray], None]
"""Called per frame with its outcome, ``rgb uint8 [H, W, 3]`` and ``depth_m float32 [H, W]``."""


def sequence_masker(
    predictor: object,
    seq: FrameSource,
    mode: str = "fusion",
    masking: MaskingSettings = DEFAULT,
    keypoints: int = 1000,
    epipolar_depth: bool = False,
    track: TrackPlan = TRACK_OFF,
    score: Sequence_[str] = (),
    feed: RecordedFeed | None = None,
) -> FrameMasker:
    """The chain ``slimseg dynamic`` runs over ``seq``: ``predictor`` (a slimseg ``Predictor``
    or ``AnnotationInstances``) at the ``track`` plan's rate (or the results of ``feed``),
    the ``score`` modes run beside the chosen one."""
    cam = seq.camera
    return FrameMasker(
        segmenter_for(predictor), class_mobility=predictor.mobility, mode=mode,
        masking=masking, track=track.settings, rate=track.rate, keypoints=keypoints,
        camera=(cam.fx, cam.fy, cam.cx, cam.cy) if epipolar_depth else None, fps=seq.fps,
        score_modes=score, feed=feed,
    )  # fmt: skip


def scored_modes(predictor: object, seq: FrameSource) -> tuple[str, ...]:
    """The modes a run scores besides its own: every mode where ground-truth ``dynamic/``
    masks exist; with ground-truth instances the epipolar check too, for its tally."""
    score = MODES if (seq.root / "dynamic").is_dir() else ()
    if isinstance(predictor, AnnotationInstances) and "semantic+epipolar" not in score:
        score = (*score, "semantic+epipolar")
    return score


@opens_sequence
def run_sequence(
    predictor: object,
    sequence: Path | FrameSource,
    out: Path,
    mode: str = "fusion",
    masking: MaskingSettings = DEFAULT,
    keypoints: int = 1000,
    progress: bool = True,
    epipolar_depth: bool = False,
    track: TrackPlan = TRACK_OFF,
    fps: float | None = None,
    observers: Sequence_[Observer] = (),
    use_depth: bool = True,
) -> SequenceReport:
    """Process every associated frame of ``sequence`` with ``predictor`` (a slimseg
    ``Predictor`` or ``AnnotationInstances``) under the ``masking`` settings (score threshold,
    dilation, Eq. 1/3/4); write masks, ``frames.csv`` and ``overlay.png`` under ``out``.
    ``epipolar_depth``: give the epipolar check the previous depth and the intrinsics
    (depth-aided residual, see ``epipolar``). ``sequence``: the folder, or it opened.
    ``track``: the track stage and the model's rate (off by default: every frame judged
    alone); with it on, ``tracks.csv`` lists every emitted object with its track id and
    source. With the model on its own thread the frames are replayed in real time at ``fps``
    (None: the sequence's own timestamps; 0: as fast as the loop goes). ``observers``: called
    with every frame's outcome, colour and depth as the run makes it (a Rerun recording, the
    boxes of a Foxglove write-back). ``use_depth`` False: the chain sees no depth image (what
    an RGB-only camera gives). A loop over
    :class:`~slimseg.dynamic.frame_masker.FrameMasker` (:func:`sequence_masker`)."""
    seq = sequence  # a path was opened by @opens_sequence
    gt = predictor if isinstance(predictor, AnnotationInstances) else None
    score = scored_modes(predictor, seq)
    live = track.rate.thread  # real time: the analysis runs on a replay afterwards
    args = (predictor, seq, mode, masking, keypoints, epipolar_depth, track)
    scored = (seq.root / "dynamic").is_dir()
    report = SequenceReport(scores={m: ModeScore() for m in MODES} if scored else {})
    analysis = _Analysis(seq, gt, report)
    with sequence_masker(*args, score=() if live else score) as m:
        live_frames = _loop(m, seq, out, report, None if live else analysis, progress, fps,
                            observers, use_depth)  # fmt: skip
    if live:
        feed = RecordedFeed([lf.delivery for lf in live_frames], lambda p: p.prediction(-1.0))
        with sequence_masker(*args, score=score, feed=feed) as m:
            for i in tqdm(range(len(seq.frames)), desc="scoring", disable=not progress):
                rgb, depth, stamp = seq.load(i)
                f = m.step(rgb, depth if use_depth else None, stamp)
                report.replay_differs += not np.array_equal(f.mask, live_frames[i].mask)
                analysis.frame(f, rgb, live_frames[i].dynamic)
    analysis.finish(out)
    return report


@dataclass(frozen=True)
class _LiveFrame:
    """What a real-time pass keeps of a frame for the analysis that follows it: the model
    result it received (packed, the frame it was computed on, lag), its mask and decisions."""

    delivery: tuple[PackedDetections | None, int, int]
    mask: np.ndarray
    dynamic: np.ndarray


class _Analysis:
    """Scores (every mode against ``dynamic/``), where recall is lost, the epipolar tally and
    the overlay panels: inline for inline rates, on a replay for a real-time run (that work
    in the live loop would take the CPU and the GIL from the model's thread)."""

    def __init__(
        self, seq: FrameSource, gt_instances: AnnotationInstances | None, report: SequenceReport
    ) -> None:
        self.report, self.gt_instances = report, gt_instances
        self.gt_dir = seq.root / "dynamic"
        ann = (seq.root / "annotations.json").is_file()
        self.losses = RecallLoss() if self.gt_dir.is_dir() and ann else None
        self.instances = _instances(gt_instances, seq.root) if self.losses is not None else None
        self.every = max(len(seq.frames) // 6, 1)
        self.panels: list[np.ndarray] = []
        self.stamps: list[float] = []

    def frame(self, f: MaskedFrame, rgb: np.ndarray, chosen: np.ndarray | None = None) -> None:
        """One frame; ``chosen``: the chosen mode's decisions as the live run made them."""
        report, result, tracked, kps = self.report, f.result, f.tracked, f.keypoints
        hw, masks, stamp = f.mask.shape, f.objects.masks, f.stamp
        if report.scores:
            gt = decode_file(self.gt_dir / mask_name(stamp), cv2.IMREAD_GRAYSCALE)
            if gt is None:
                report.skipped.append(str(self.gt_dir / mask_name(stamp)))
            else:
                truth = at_keypoints(gt > 0, kps)
                for m, res in f.results.items():
                    own = chosen is not None and m == f.mode
                    report.scores[m].add(chosen if own else res.dynamic, truth)
                if self.losses is not None:
                    only = coasted_only(tracked, masks, hw)
                    self.losses.add(self.instances, stamp, kps, result.dynamic, truth,
                                    result.mask > 0, only)  # fmt: skip
        self.stamps.append(stamp)
        _tally(report, self.gt_instances, f, self.stamps)
        if f.index % self.every == 0 and len(self.panels) < 6:
            ghost = None if tracked is None else coasted_only(tracked, masks, hw)
            self.panels.append(overlay(rgb, result.mask, kps, result.dynamic, ghost))

    def finish(self, out: Path) -> None:
        if self.losses is not None:
            self.report.recall_loss = self.losses.finish()
        if self.panels:
            write_png(out / "overlay.png", tile(self.panels, 3))


def _loop(
    masker: FrameMasker,
    seq: FrameSource,
    out: Path,
    report: SequenceReport,
    analysis: _Analysis | None,
    progress: bool,
    fps: float | None,
    observers: Sequence_[Observer] = (),
    use_depth: bool = True,
) -> list[_LiveFrame]:
    """The run: masks, ``frames.csv``, ``tracks.csv`` and the timing figures of ``report``;
    ``analysis`` per frame (None: a real-time run, which returns what the analysis replays)."""
    (out / "masks").mkdir(parents=True, exist_ok=True)
    report.rate = masker.rate.describe()
    rows, tracks, kept = [], [], []
    t_model = t_logic = 0.0
    live = masker.rate.thread  # frames replayed in real time
    clock = _Replay(fps if live else 0.0, masker.clock)
    keep = masker.masking.keep_score
    for i in tqdm(range(len(seq.frames)), desc="dynamic", disable=not progress):
        rgb, depth, stamp = seq.load(i)
        arrival = clock.arrive(i, stamp)
        taken = masker.clock()
        depth = depth if use_depth else None
        f = masker.step(rgb, depth, stamp)
        for observe in observers:
            observe(f, rgb, depth)
        result, tracked, hw = f.result, f.tracked, f.mask.shape
        report.model_frames += f.model_ran
        report.latency_ms.append(f.timing.latency)
        if live:
            report.late_ms.append(1000 * max(taken - arrival, 0.0))
            packed = None if f.prediction is None else PackedDetections.of(f.prediction, hw)
            kept.append(_LiveFrame((packed, i - f.lag, f.lag), f.mask, f.dynamic))
        t_logic += f.timing.masking / 1000  # the chosen mode only, not the scoring of the rest
        t_model += f.timing.model / 1000  # the loop's time in the model (inline), or waiting
        if tracked is not None:
            report.coasted += int(tracked.coasted.sum())
            tracks += track_rows(stamp, tracked)
        write_png(out / "masks" / mask_name(stamp), result.mask)
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
        if analysis is not None:
            analysis.frame(f, rgb)
        report.frames += 1
    write_csv(out / "frames.csv", rows)
    stage, feed = masker.stage, masker.feed
    if stage is not None:
        write_csv(out / "tracks.csv", tracks)
    n = max(report.frames, 1)
    report.ms_per_frame = {"model": 1000 * t_model / n, "masking_logic": 1000 * t_logic / n}
    if stage is not None:  # its time is inside masking_logic (preparation); shown apart too
        report.ms_per_frame["track_stage"] = stage.ms_per_frame
        report.stage_parts_ms = {k: 1000 * v / n for k, v in stage.tracker.parts.items()}
    report.model_lags = list(feed.lags)
    report.model_ms_per_run = 1000 * feed.model_s / max(feed.model_runs, 1)
    if live:  # the loop waited for the model only on the first frame: count its runs' time
        report.ms_per_frame["model_thread"] = 1000 * feed.model_s / n
    return kept


def _tally(
    report: SequenceReport,
    gt_instances: AnnotationInstances | None,
    f: MaskedFrame,
    stamps: list[float],
) -> None:
    """The epipolar check's decisions of frame ``f`` against ground-truth instances (``stamps``:
    every frame's so far; a late result's detections belong to an older frame)."""
    epi_mode = f.mode if f.mode in EPIPOLAR_MODES else "semantic+epipolar"
    if gt_instances is None or f.index == 0 or epi_mode not in f.results:
        return
    seen = stamps[f.index - f.lag] if f.model_ran else f.stamp
    _count_epipolar(report, gt_instances, seen, f.results[epi_mode], f.tracked)


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
