"""The model's rate in a sequence loop: a time budget, and the model on its own thread with
late results moved into the current frame (docs/tracking.md section 6)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from slimseg.cli.main import main
from slimseg.data.synth.sequence import write_sequence
from slimseg.dynamic.annotations import AnnotationInstances
from slimseg.dynamic.camera_motion import CameraMotion
from slimseg.dynamic.chain_config import ChainConfig, TrackPlan
from slimseg.dynamic.frame_masker import FrameMasker
from slimseg.dynamic.model_feed import MAX_EVERY, ModelFeed
from slimseg.dynamic.model_rate import ModelRate
from slimseg.dynamic.track import Tracker
from slimseg.dynamic.track_run import move_dets
from slimseg.dynamic.track_settings import COAST
from slimseg.errors import SlimsegError
from slimseg.objects import Objects
from slimseg.sequence.sequence_run import run_sequence

HW = (120, 160)


def _pred(tag: float) -> Objects:
    """A result whose one (box-only) object scores ``tag``."""
    return Objects(np.zeros((1, 4), np.float32), np.array([tag], np.float32), [0], None, HW)


class _Slow:
    """A segmenter taking ``seconds`` per frame; its prediction carries the frame's stamp."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds

    def __call__(self, rgb: np.ndarray, stamp: float) -> Objects:
        time.sleep(self.seconds)
        return _pred(stamp)


def test_thread_feeds_the_newest_result_with_its_lag() -> None:
    feed = ModelFeed(_Slow(0.03), ModelRate.own_thread())
    rgb = np.zeros((*HW, 3), np.uint8)
    got = []
    try:
        for i in range(12):
            got.append(feed.frame(i, rgb, float(i)))
            time.sleep(0.01)  # the loop's own work per frame
    finally:
        feed.close()
    assert got[0].objects is not None and got[0].lag == 0  # the first frame waits for its own
    used = [g for g in got[1:] if g.objects is not None]
    assert 2 <= len(used) <= 8, len(used)  # ~ one result per 3-4 frames, never every frame
    for k, g in enumerate(got):
        if g.objects is not None:  # the result is the frame it says it is, `lag` frames back
            assert g.objects.scores[0] == g.index and g.lag == k - g.index >= 0
    assert all(g.lag >= 1 for g in used) and feed.model_runs == len(used) + 1


def test_budget_picks_the_model_rate() -> None:
    feed = ModelFeed(_Slow(0.03), ModelRate.budget(12.5))
    rgb = np.zeros((*HW, 3), np.uint8)
    ran = []
    for i in range(20):
        ran.append(feed.frame(i, rgb, float(i)).objects is not None)
        feed.other_time(0.005)
    gaps = np.diff(np.flatnonzero(ran))
    # model >= 30 ms, the rest 5 ms: (30 / N + 5) <= 12.5 needs N >= 4 (a loaded machine
    # oversleeps: up to 7)
    assert gaps[0] == 1 and all(4 <= g <= 7 for g in gaps[2:]), gaps
    exact = ModelFeed(_Slow(0.0), ModelRate.budget(12.5))
    exact.model_runs, exact.model_s = 4, 0.12  # 30 ms per run
    exact.other_time(0.005)
    assert exact.gap() == 4
    assert ModelFeed(_Slow(0.0), ModelRate.budget(1.0)).gap() == 1  # nothing measured yet
    tight = ModelFeed(_Slow(0.0), ModelRate.budget(1.0))
    tight.model_runs, tight.model_s = 5, 0.1
    tight.other_time(0.002)  # the rest alone is over budget: the slowest rate
    assert tight.gap() == MAX_EVERY


def test_rate_is_one_of_three_and_needs_the_track_stage() -> None:
    with pytest.raises(SlimsegError, match="give one of"):
        ModelRate(every=2, budget_ms=10)
    with pytest.raises(SlimsegError, match="needs the track stage"):
        TrackPlan(None, ModelRate.own_thread())
    with pytest.raises(SlimsegError, match="budget nan"):
        ModelRate.budget(float("nan"))
    with pytest.raises(SlimsegError, match="needs the track stage"):
        ChainConfig(track=TrackPlan(None, ModelRate.every_n(2)))
    assert [ModelRate.parse(t).name for t in ("per-frame", "3", "budget:25", "thread")] == [
        "per-frame", "every 3", "budget 25 ms", "own thread"]  # fmt: skip
    with pytest.raises(SlimsegError, match="expected N, budget:MS or thread"):
        ModelRate.parse("fast")


def _disc(cx: float, cy: float, r: float = 12) -> np.ndarray:
    yy, xx = np.mgrid[: HW[0], : HW[1]]
    return (xx - cx) ** 2 + (yy - cy) ** 2 <= r * r


def _dets(cx: float, score: float = 0.9) -> Objects:
    m = _disc(cx, 60)
    return Objects(np.array([[cx - 12, 48, cx + 13, 73]], np.float32),
                   np.array([score], np.float32), np.zeros(1, np.int64), m[None], HW)  # fmt: skip


def test_late_detections_are_moved_by_the_camera_then_by_the_object() -> None:
    h = np.array([[1, 0, 7.0], [0, 1, -3.0], [0, 0, 1]])
    moved = move_dets(_dets(40), h)
    assert np.array_equal(moved.masks[0], _disc(47, 57))
    assert moved.boxes[0].tolist() == [35, 45, 60, 70]
    tr = Tracker(COAST, np.array([1.0]))
    for k in range(10):  # a disc moving 4 px per frame, seen every frame
        tr.step(_dets(20 + 4 * k), CameraMotion.identity(), 0.1)
    tr.step(None, CameraMotion.identity(), 0.1)
    # frame 11 gets frame 9's result (lag 2): the disc is now 8 px further on
    f = tr.step(_dets(56), CameraMotion.identity(), 0.1, lag=2)
    xs = np.nonzero(f.masks[0])[1]
    assert f.source.tolist() == ["det"] and xs.mean() == pytest.approx(64, abs=1.5)
    assert tr.step(_dets(60), CameraMotion.identity(), 0.1).masks[0].sum() > 0


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("feed") / "seq"
    write_sequence(root, seed=7, index=0, frames=30, size=(320, 240), preset="walking_xyz")
    return root


def test_run_sequence_with_the_model_on_its_own_thread(sequence: Path, tmp_path: Path) -> None:
    inst = AnnotationInstances(sequence)
    per = run_sequence(inst, sequence, tmp_path / "p", ChainConfig(mode="seg"), progress=False)
    live = run_sequence(
        inst,
        sequence,
        tmp_path / "t",
        ChainConfig(mode="seg", track=TrackPlan(COAST, ModelRate.own_thread())),
        progress=False,
        replay_fps=60.0,
    )
    assert live.frames == 30 and len(live.latency_ms) == 30 and live.model_lags[0] == 0
    assert len(list((tmp_path / "t" / "masks").glob("*.png"))) == 30
    # every mode is scored whatever the rate (on the trace, after the run)
    assert live.scores["fusion"].tp > 0 and live.scores["box"].tp > 0
    assert live.scores["seg"].recall >= 0.8 * per.scores["seg"].recall
    assert "model_thread" in live.ms_per_frame and live.stage_parts_ms["motion"] > 0


def test_cli_rates_and_their_errors(sequence: Path, tmp_path: Path, capsys) -> None:
    base = ["dynamic", "--gt-instances", "--sequence", str(sequence), "--mode", "seg",
            "--quiet", "--out", str(tmp_path / "o")]  # fmt: skip
    assert main([*base, "--track", "--rate", "thread", "--fps", "0"]) == 0
    text = capsys.readouterr().out
    assert "latency per frame (model on its own thread)" in text and "replay kept up" in text
    assert "track stage per frame by part (ms): motion" in text
    assert main([*base, "--track", "--rate", "budget:50"]) == 0
    assert "budget of 50 ms" in capsys.readouterr().out
    for bad, msg in (
        (["--fps", "5"], "add --rate thread"),
        (["--track", "--rate", "thread", "--fps", "-1"], "--fps -1"),
        (["--track", "--rate", "sometimes"], "expected N, budget:MS or thread"),
        (["--rate", "thread"], "needs the track stage"),
    ):
        assert main([*base, *bad]) == 2
        err = capsys.readouterr().err
        assert msg in err and len(err.strip().splitlines()) == 1, err


def test_a_real_time_runs_kept_trace_is_analysed_as_inline(sequence: Path, tmp_path: Path) -> None:
    """A real-time run keeps its trace (masks as crops, no depth) and analyses it after the
    run: every mode's score, the recall split and the epipolar tally come out as when the
    same frames are analysed as they arrive; the chosen mode, run again on the trace, masks
    every frame as the live chain did."""
    from slimseg.data.tum import TumSequence
    from slimseg.dynamic.frame_masker import segmenter_for
    from slimseg.dynamic.modes import MODES
    from slimseg.dynamic.occupancy import MotionLayers
    from slimseg.dynamic.pipeline import apply_rules
    from slimseg.sequence.sequence_report import ModeScore, SequenceReport
    from slimseg.sequence.trace_analysis import TraceAnalysis

    inst, seq = AnnotationInstances(sequence), TumSequence(sequence)
    slow = segmenter_for(inst)

    def segment(rgb, stamp, conf):
        time.sleep(0.04)  # a model slower than the loop: results arrive late
        return slow(rgb, stamp, conf)

    config = ChainConfig(mode="fusion", track=TrackPlan(COAST, ModelRate.own_thread()),
                         fps=seq.fps)  # fmt: skip
    with FrameMasker(segment, inst.mobility, config) as m:
        frames = [m.step(*seq.load(i)) for i in range(len(seq))]
        rules = m.rules
    assert max(f.lag or 0 for f in frames) >= 1  # some results were late
    for f in frames:  # the rules again, on the trace's inputs and the decided mobility
        moved = MotionLayers.of(f.inputs, rules.masking)
        assert np.array_equal(apply_rules(f.inputs, f.decision, rules, moved=moved).mask, f.mask)
    reports = []
    for deferred in (False, True):
        report = SequenceReport(scores={k: ModeScore() for k in MODES})
        analysis = TraceAnalysis(seq, inst, report, rules, MODES, deferred)
        for i, f in enumerate(frames):
            analysis.observe(f, seq.load(i)[0])
        analysis.finish(tmp_path)
        reports.append(report)
    inline, kept = reports
    assert {k: vars(v) for k, v in kept.scores.items()} == {
        k: vars(v) for k, v in inline.scores.items()}  # fmt: skip
    assert kept.scores["box"].tp > 0 and kept.epipolar == inline.epipolar
    assert str(kept.recall_loss.summary()) == str(inline.recall_loss.summary())  # NaNs too
