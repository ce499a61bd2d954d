"""Run the reference masking logic over a TUM RGB-D sequence, optionally scoring it.

Per frame, :class:`~slimseg.dynamic.frame_masker.FrameMasker` (model → detections in frame
pixels → ORB keypoints → track stage → the chosen mode) → ``masks/<rgb timestamp>.png``
(uint8, 255 = dynamic; the offline mask-cache convention of DynaSLAM-style runtimes) and a
CSV row. When the sequence has ground-truth ``dynamic/`` masks (the synthetic generator
writes them), :class:`~slimseg.sequence.trace_analysis.TraceAnalysis` scores every mode on
the inputs the chain's rules saw: precision and recall of dynamic keypoints.

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
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from slimseg.data.frame_source import FrameSource
from slimseg.data.sequence_source import opens_sequence
from slimseg.data.tum import mask_name
from slimseg.dynamic.annotations import AnnotationInstances
from slimseg.dynamic.chain_config import DEFAULT_CHAIN, ChainConfig
from slimseg.dynamic.frame_masker import FrameMasker, segmenter_for
from slimseg.dynamic.masked_frame import MaskedFrame
from slimseg.dynamic.modes import MODES, Mode
from slimseg.sequence.sequence_report import ModeScore, SequenceReport, track_rows, write_csv
from slimseg.sequence.trace_analysis import TraceAnalysis
from slimseg.utils.atomic import write_png

Observer = Callable[[MaskedFrame, np.ndarray, np.ndarray], None]
"""Called per frame with its outcome, ``rgb uint8 [H, W, 3]`` and ``depth_m float32 [H, W]``."""


def sequence_config(seq: FrameSource, config: ChainConfig = DEFAULT_CHAIN) -> ChainConfig:
    """``config`` for ``seq``: its frame rate, and its intrinsics where ``config`` gives
    none (the depth cut's motion layers, the stillness test, the depth-aided residual)."""
    camera = seq.camera.pinhole if config.camera is None else config.camera
    return replace(config, camera=camera, fps=seq.fps)


def scored_modes(predictor: object, seq: FrameSource) -> tuple[str, ...]:
    """The modes a run scores besides its own: every mode where ground-truth ``dynamic/``
    masks exist; with ground-truth instances the epipolar check too, for its tally."""
    score = MODES if (seq.root / "dynamic").is_dir() else ()
    if isinstance(predictor, AnnotationInstances) and Mode.SEMANTIC_EPIPOLAR not in score:
        score = (*score, Mode.SEMANTIC_EPIPOLAR.value)
    return score


@opens_sequence
def run_sequence(
    predictor: object,
    sequence: Path | FrameSource,
    out: Path,
    config: ChainConfig = DEFAULT_CHAIN,
    *,
    progress: bool = True,
    replay_fps: float | None = None,
    observers: Sequence_[Observer] = (),
    use_depth: bool = True,
) -> SequenceReport:
    """Process every associated frame of ``sequence`` with ``predictor`` (a slimseg
    ``Predictor`` or ``AnnotationInstances``) through the chain ``config`` says (mode, masking
    settings, track stage and rate, keypoints; the sequence's frame rate and intrinsics
    filled in by :func:`sequence_config`); write masks, ``frames.csv`` and ``overlay.png``
    under ``out``. ``sequence``: the folder, or it opened. With the track stage on,
    ``tracks.csv`` lists every emitted object with its track id and source. With the model on
    its own thread the frames are replayed in real time at ``replay_fps`` (None: the
    sequence's own timestamps; 0: as fast as the loop goes). ``observers``: called with every
    frame's outcome, colour and depth as the run makes it (a Rerun recording, the boxes of a
    Foxglove write-back). ``use_depth`` False: the chain sees no depth image (what an
    RGB-only camera gives). A loop over :class:`~slimseg.dynamic.frame_masker.FrameMasker`."""
    seq = sequence  # a path was opened by @opens_sequence
    gt = predictor if isinstance(predictor, AnnotationInstances) else None
    config = sequence_config(seq, config)
    scored = (seq.root / "dynamic").is_dir()
    report = SequenceReport(scores={m: ModeScore() for m in MODES} if scored else {})
    with FrameMasker(segmenter_for(predictor), predictor.mobility, config) as m:
        live = config.track.rate.thread  # real time: the analysis runs after the run
        analysis = TraceAnalysis(seq, gt, report, m.rules, scored_modes(predictor, seq), live)
        _loop(m, seq, out, report, analysis, progress, replay_fps, observers, use_depth)
    analysis.finish(out, use_depth)
    return report


def _loop(
    masker: FrameMasker,
    seq: FrameSource,
    out: Path,
    report: SequenceReport,
    analysis: TraceAnalysis,
    progress: bool,
    fps: float | None,
    observers: Sequence_[Observer] = (),
    use_depth: bool = True,
) -> None:
    """The run: masks, ``frames.csv``, ``tracks.csv`` and the timing figures of ``report``;
    every frame to the ``analysis``."""
    (out / "masks").mkdir(parents=True, exist_ok=True)
    rate = masker.config.track.rate
    report.rate = rate.describe()
    rows, tracks = [], []
    t_model = t_logic = 0.0
    live = rate.thread  # frames replayed in real time
    clock = _Replay(fps if live else 0.0)
    keep = masker.config.masking.keep_score
    stage = masker.stage
    for i in tqdm(range(len(seq.frames)), desc="dynamic", disable=not progress):
        rgb, depth, stamp = seq.load(i)
        arrival = clock.arrive(i, stamp)
        taken = time.perf_counter()
        depth = depth if use_depth else None
        f = masker.step(rgb, depth, stamp)
        for observe in observers:
            observe(f, rgb, depth)
        result, objects = f.result, f.objects
        report.model_frames += f.model_ran
        report.latency_ms.append(f.timing.latency)
        if live:
            report.late_ms.append(1000 * max(taken - arrival, 0.0))
        t_logic += f.timing.masking / 1000  # the chosen mode only
        t_model += f.timing.model / 1000  # the loop's time in the model (inline), or waiting
        if stage is not None:
            report.coasted += int(objects.predicted.sum())
            tracks += track_rows(stamp, objects)
        write_png(out / "masks" / mask_name(stamp), result.mask)
        confident = int((objects.scores[np.asarray(result.dropped, int)] >= keep).sum())
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
                "still": 0 if f.inputs.still is None else int(f.inputs.still.sum()),
                "dynamic_frame": result.dynamic_frame,
                "used_seg": result.used_seg,
                "detections": len(objects),
                "model_ms": round(f.timing.model, 2),
                **({} if stage is None else {"coasted": int(objects.predicted.sum())}),
            }
        )
        analysis.observe(f, rgb)
        report.frames += 1
    write_csv(out / "frames.csv", rows)
    feed = masker.feed
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


class _Replay:
    """Frame arrival times: the sequence's timestamps (``fps`` None) or ``i / fps`` from the
    first frame, in real time (``time.perf_counter``); ``fps`` 0: each frame arrives when the
    loop asks for it."""

    def __init__(self, fps: float | None) -> None:
        self.fps = fps
        self.first: tuple[float, float] | None = None  # (clock, stamp) of frame 0

    def arrive(self, i: int, stamp: float) -> float:
        """Wait until frame ``i`` arrives; return its arrival time (``perf_counter`` s)."""
        now = time.perf_counter()
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
