"""The track stage: its parts on hand-made cases, and what it buys on a synthetic sequence
whose ground-truth instances go missing in bursts."""

from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from slimseg.cli.main import main
from slimseg.data.synth.sequence import write_sequence
from slimseg.dynamic.annotations import AnnotationInstances, Dropout
from slimseg.dynamic.camera_motion import CameraMotion, estimate_motion
from slimseg.dynamic.chain_config import ChainConfig, TrackPlan
from slimseg.dynamic.epipolar import OrbFeatures
from slimseg.dynamic.kalman import BoxKalman
from slimseg.dynamic.mask_patch import (
    Patch,
    dilate_patch,
    patch_from_mask,
    patch_iou,
    warp_patch,
)
from slimseg.dynamic.model_rate import ModelRate
from slimseg.dynamic.track import Tracker
from slimseg.dynamic.track_belief import TrackBeliefs
from slimseg.dynamic.track_settings import COAST, NO_COAST, TrackSettingsError
from slimseg.errors import SlimsegError
from slimseg.objects import Objects
from slimseg.sequence.sequence_run import run_sequence

HW = (120, 160)


def _disc(cx: float, cy: float, r: float = 12, hw=HW) -> np.ndarray:
    yy, xx = np.mgrid[: hw[0], : hw[1]]
    return (xx - cx) ** 2 + (yy - cy) ** 2 <= r * r


def _dets(masks: list[np.ndarray], scores: list[float]) -> Objects:
    boxes = []
    for m in masks:
        ys, xs = np.nonzero(m)
        boxes.append([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1])
    return Objects(
        np.array(boxes, np.float32).reshape(-1, 4),
        np.array(scores, np.float32),
        np.zeros(len(masks), np.int64),
        np.array(masks, bool).reshape(-1, *HW),
        HW,
    )


# -- parts -----------------------------------------------------------------------------------


def test_patch_ops_match_full_frame_masks() -> None:
    a, b = _disc(50, 60), _disc(58, 60)
    pa, pb = patch_from_mask(a), patch_from_mask(b)
    full = (a & b).sum() / (a | b).sum()
    assert patch_iou(pa, pb) == pytest.approx(full)
    shift = np.array([[1, 0, 8], [0, 1, 0], [0, 0, 1.0]])
    assert np.array_equal(warp_patch(pa, shift, HW).paste(HW), b)
    grown = dilate_patch(pa, 3, HW).paste(HW)
    assert grown.sum() > a.sum() and grown[a].all()
    off = np.array([[1, 0, 500], [0, 1, 0], [0, 0, 1.0]])
    assert warp_patch(pa, off, HW).area == 0  # left the frame: empty, no error
    assert Patch(0, 0, np.zeros((0, 0), bool)).area == 0


def test_kalman_learns_a_constant_velocity() -> None:
    kf = BoxKalman(np.array([10, 20, 30, 60.0]))
    for k in range(1, 12):
        kf.predict(CameraMotion.identity())
        kf.update(np.array([10 + 4 * k, 20, 30 + 4 * k, 60.0]))
    assert kf.velocity[0] == pytest.approx(4, abs=0.3)
    kf.predict(CameraMotion.identity())
    assert kf.box[0] == pytest.approx(10 + 4 * 12, abs=1.0)


def test_kalman_follows_the_camera() -> None:
    kf = BoxKalman(np.array([10, 20, 30, 60.0]))
    shift = CameraMotion(np.array([[1, 0, 7], [0, 1, -3], [0, 0, 1.0]]), True)
    kf.predict(shift)
    assert kf.box == pytest.approx([17, 17, 37, 57], abs=1e-6)


def test_camera_motion_from_shifted_features_ignores_objects() -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform([0, 0], [640, 480], (400, 2)).astype(np.float32)
    desc = rng.integers(0, 256, (400, 32), dtype=np.uint8)
    moved = pts + np.float32([5, -2])
    mover = (pts[:, 0] > 300) & (pts[:, 0] < 400)  # an object moving on its own
    moved[mover] += np.float32([40, 0])
    motion = estimate_motion(OrbFeatures(pts, desc), OrbFeatures(moved, desc),
                             np.array([[340, 0, 440, 480]]))  # fmt: skip
    assert motion.ok
    assert motion.H[:2, 2] == pytest.approx([5, -2], abs=0.05)
    too_few = estimate_motion(OrbFeatures(pts[:10], desc[:10]), OrbFeatures(moved[:10], desc[:10]))
    assert not too_few.ok and np.array_equal(too_few.H, np.eye(3))


def test_settings_refuse_bad_values() -> None:
    with pytest.raises(TrackSettingsError, match="max_coast"):
        COAST.with_values(max_coast=-1)
    with pytest.raises(TrackSettingsError, match="low"):
        COAST.with_values(low=0.5, high=0.25)
    with pytest.raises(SlimsegError, match="needs the track stage"):
        TrackPlan(None, ModelRate.every_n(3))


def test_dropout_schedule() -> None:
    d = Dropout(0.2, 3, seed=4)
    flags = d.dropped(7, 90)
    assert flags.mean() == pytest.approx(0.2, abs=0.01)
    runs = np.diff(np.flatnonzero(np.diff(np.r_[0, flags.astype(int), 0])))[::2]
    assert set(runs.tolist()) == {3}  # bursts never merge
    assert np.array_equal(flags, Dropout(0.2, 3, seed=4).dropped(7, 90))
    assert not np.array_equal(flags, Dropout(0.2, 3, seed=5).dropped(7, 90))
    assert Dropout.parse("0.1:3:2") == Dropout(0.1, 3, 2)
    with pytest.raises(SlimsegError, match="RATE:BURST"):
        Dropout.parse("0.1")


# -- the tracker on hand-made frames -----------------------------------------------------------


def _run(settings, frames, depth=None):
    tr = Tracker(settings, np.array([1.0]))
    out = []
    for dets in frames:
        out.append(tr.step(dets, CameraMotion.identity(), 0.1, depth))
    return tr, out


def test_coasting_carries_a_moving_mask_over_a_gap() -> None:
    frames = [_dets([_disc(30 + 4 * k, 60)], [0.9]) for k in range(6)]
    frames += [_dets([], []) for _ in range(2)]  # two missed frames
    _, out = _run(COAST, frames)
    gap = out[6]
    assert gap.source == ["coast"] and gap.misses.tolist() == [1]
    assert gap.mobility[0] == pytest.approx(COAST.coast_decay)
    # predicted where the disc would be (x 54), not where it was last seen (x 50)
    xs = np.nonzero(gap.masks[0])[1]
    assert xs.mean() == pytest.approx(54, abs=1.5)
    assert out[7].mobility[0] == pytest.approx(COAST.coast_decay**2)
    _, plain = _run(NO_COAST, frames)
    assert len(plain[6].boxes) == 0


def test_coasting_stops_after_k_and_tentative_tracks_never_coast() -> None:
    frames = [_dets([_disc(40, 60)], [0.9])] * 3 + [_dets([], [])] * 5
    _, out = _run(COAST.with_values(max_coast=2), frames)
    assert [len(f.boxes) for f in out[3:]] == [1, 1, 0, 0, 0]
    weak = [_dets([_disc(40, 60)], [0.3])] + [_dets([], [])] * 2  # score < confirm, one hit
    _, out = _run(COAST, weak)
    assert [len(f.boxes) for f in out] == [1, 0, 0]


def test_tentative_tracks_are_carried_until_the_next_model_frame_misses_them() -> None:
    tr = Tracker(COAST, np.array([1.0]))
    weak = _dets([_disc(40, 60)], [0.15])  # emitted (> 0.1), below high/new/confirm
    out = [tr.step(weak, CameraMotion.identity(), 0.1)]
    out += [tr.step(None, CameraMotion.identity(), 0.1) for _ in range(2)]  # model skipped
    assert [f.source for f in out] == [["det"], ["carried"], ["carried"]]
    assert not tr.tracks[0].confirmed
    out.append(tr.step(_dets([], []), CameraMotion.identity(), 0.1))  # the model misses it
    assert len(out[-1].boxes) == 0 and not tr.tracks
    again = [weak, None, weak]  # found again on the next model frame: the same track, but
    tr = Tracker(COAST, np.array([1.0]))  # a weak one (< new) is never confirmed: no coasting
    for d in again:
        f = tr.step(d, CameraMotion.identity(), 0.1)
    assert f.track_ids.tolist() == [1] and tr.tracks[0].hits == 2
    assert not tr.tracks[0].confirmed
    assert set(tr.parts) >= {"predict", "associate", "warp", "coast"}


def test_depth_gate_ends_a_track_whose_walker_left() -> None:
    depth = np.full(HW, 4.0, np.float32)
    here = _disc(60, 60)
    depth[here] = 2.0
    tr = Tracker(COAST, np.array([1.0]))
    for _ in range(3):
        tr.step(_dets([here], [0.9]), CameraMotion.identity(), 0.1, depth)
    gone = np.full(HW, 4.0, np.float32)  # the walker left: only the wall behind remains
    f = tr.step(_dets([], []), CameraMotion.identity(), 0.1, gone)
    assert len(f.boxes) == 0 and not tr.tracks


def test_byte_second_pass_recovers_low_scores_only_for_confirmed_tracks() -> None:
    frames = [_dets([_disc(40, 60)], [0.9])] * 3 + [_dets([_disc(41, 60)], [0.07])]
    _, out = _run(COAST, frames)
    assert out[3].source == ["det"] and out[3].track_ids[0] > 0  # below the masking 0.1
    lone = [_dets([_disc(40, 60)], [0.07])]
    _, out = _run(COAST, lone)
    assert len(out[0].boxes) == 0  # an unbacked low score stays dropped, as per frame


def test_moving_probability_relaxes_and_updates() -> None:
    tr, out = _run(COAST, [_dets([_disc(40, 60)], [0.9])] * 2)
    mob = out[-1].mobility
    for _ in range(5):
        mob = TrackBeliefs(tr).observe_motion(out[-1], [0], np.array([True]), np.array([False]))
    assert mob[0] == pytest.approx((1 - COAST.p_alpha) ** 5)
    assert mob[0] < 0.25  # a standing person's points stay static after a few decisions


# -- on a synthetic sequence -----------------------------------------------------------------


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("track") / "seq"
    write_sequence(root, seed=5, index=0, frames=45, size=(320, 240), preset="walking_xyz")
    return root


def _digest(folder: Path) -> str:
    h = hashlib.sha1()
    for p in sorted((folder / "masks").glob("*.png")):
        h.update(p.read_bytes())
    return h.hexdigest()


def test_off_is_the_per_frame_output(sequence: Path, tmp_path: Path) -> None:
    inst = AnnotationInstances(sequence)
    a = run_sequence(inst, sequence, tmp_path / "a", ChainConfig(mode="fusion"), progress=False)
    run_sequence(
        inst,
        sequence,
        tmp_path / "b",
        ChainConfig(mode="fusion", track=TrackPlan()),
        progress=False,
    )
    assert _digest(tmp_path / "a") == _digest(tmp_path / "b")
    assert not (tmp_path / "b" / "tracks.csv").exists() and a.recall_loss is not None


def test_tracks_win_back_dropped_instances(sequence: Path, tmp_path: Path) -> None:
    dropped = AnnotationInstances(sequence, Dropout(0.2, 3, seed=1))
    assert dropped.dropped > 0
    off = run_sequence(dropped, sequence, tmp_path / "off", ChainConfig(mode="seg"), progress=False)
    on = run_sequence(
        dropped,
        sequence,
        tmp_path / "on",
        ChainConfig(mode="seg", track=TrackPlan(COAST)),
        progress=False,
    )
    r_off, r_on = off.scores["seg"].recall, on.scores["seg"].recall
    assert r_off < 0.97 and (1 - r_on) < 0.3 * (1 - r_off), (r_off, r_on)  # >= 70 % won back
    assert on.scores["seg"].precision >= off.scores["seg"].precision - 0.02
    loss_off, loss_on = off.recall_loss.summary(), on.recall_loss.summary()
    assert loss_off["missed_on_dropouts_pct"] > 50
    assert loss_on["dropout_frames_pct"] < loss_off["dropout_frames_pct"] / 3
    assert (tmp_path / "on" / "tracks.csv").is_file() and on.coasted > 0


def test_segment_every_runs_the_model_on_every_nth_frame(sequence: Path, tmp_path: Path) -> None:
    inst = AnnotationInstances(sequence)
    rep = run_sequence(inst, sequence, tmp_path / "x", ChainConfig(mode="seg"), progress=False)
    every3 = run_sequence(
        inst,
        sequence,
        tmp_path / "e3",
        ChainConfig(mode="seg", track=TrackPlan(COAST, ModelRate.every_n(3))),
        progress=False,
    )
    assert every3.model_frames == 15 and rep.model_frames == 45
    assert every3.scores["seg"].recall > 0.8 * rep.scores["seg"].recall


class _WeakInstances(AnnotationInstances):
    """Ground-truth instances scored like the demo model's walkers: above the masking
    threshold (0.1) but below BYTE's ``high`` and the old ``new`` (0.25)."""

    def for_stamp(self, stamp: float):
        pred = super().for_stamp(stamp)
        return replace(pred, scores=np.full_like(pred.scores, 0.15))


@pytest.mark.parametrize(("every", "kept"), [(2, 0.95), (3, 0.95), (5, 0.85)])
def test_carried_frames_keep_what_the_model_frames_found(
    sequence: Path, tmp_path: Path, every: int, kept: float
) -> None:
    """Every emitted detection opens a track, so the frames the model skips keep the weak
    walkers (before: they opened no track and vanished, recall fell to about 1/N)."""
    weak = _WeakInstances(sequence)
    per = run_sequence(weak, sequence, tmp_path / "p", ChainConfig(mode="seg"), progress=False)
    carried = run_sequence(
        weak,
        sequence,
        tmp_path / f"e{every}",
        ChainConfig(mode="seg", track=TrackPlan(COAST, ModelRate.every_n(every))),
        progress=False,
    )
    r_per, r_car = per.scores["seg"].recall, carried.scores["seg"].recall
    assert r_per > 0.9 and r_car >= kept * r_per, (r_per, r_car)
    assert carried.scores["seg"].precision >= per.scores["seg"].precision - 0.05


def test_cli_dynamic_track_and_errors(sequence: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "cli"
    rc = main(["dynamic", "--gt-instances", "--sequence", str(sequence), "--out", str(out),
               "--mode", "seg", "--track", "--set", "max_coast=5", "--gt-dropout", "0.1:3",
               "--quiet"])  # fmt: skip
    text = capsys.readouterr().out
    assert rc == 0 and "max_coast 5" in text and "where recall is lost" in text
    assert "where precision is lost: " in text
    assert (out / "tracks.csv").read_text().startswith("timestamp,track_id")
    for bad, msg in (
        (["--rate", "2"], "needs the track stage"),
        (["--set", "high=2"], "setting high = 2.0"),
        (["--track", "nope"], "invalid choice"),
    ):
        args = ["dynamic", "--gt-instances", "--sequence", str(sequence), "--out", str(out),
                "--quiet", *bad]  # fmt: skip
        try:
            rc = main(args)
        except SystemExit as e:  # argparse's own refusals
            rc = e.code
        assert rc != 0 and msg in capsys.readouterr().err


@pytest.mark.parametrize(
    ("mode", "every"), [("fusion", 1), ("fusion+epipolar", 2), ("box+depth-ransac", 3)]
)
def test_cached_sweep_loop_gives_the_same_tracked_masks(
    sequence: Path, tmp_path: Path, mode: str, every: int
) -> None:
    """slam-eval --sweep (cached detections) and slimseg dynamic agree under the stage: one
    chain (FrameMasker), the same depth, previous frame and model schedule in both."""
    from slimseg.data.tum import TumSequence
    from slimseg.dynamic.masking_settings import DEFAULT
    from slimseg.sequence.detection_cache import build_cache, mask_with

    inst = AnnotationInstances(sequence, Dropout(0.2, 3, seed=2))
    plan = TrackPlan(COAST, ModelRate.every_n(every))
    run_sequence(
        inst,
        sequence,
        tmp_path / "dyn",
        ChainConfig(mode=mode, masking=DEFAULT, track=plan),
        progress=False,
    )
    seq = TumSequence(sequence)
    cache = build_cache(inst, seq, plan.floor(DEFAULT.conf), progress=False)
    sm = mask_with(cache, mode, DEFAULT, tmp_path / "sweep" / "masks", plan)
    assert sm.model_share == pytest.approx(1 / every)
    assert _digest(tmp_path / "dyn") == _digest(tmp_path / "sweep")


@pytest.mark.slow
def test_slam_eval_tracked_conditions(sequence: Path, tmp_path: Path, capsys) -> None:
    """slam-eval runs the mask modes through the stage and says so in the condition name;
    --sweep runs every setting tracked (the dense engine: no vocabulary needed)."""
    import json

    pytest.importorskip("evo", reason="the [slam] extra (make test installs it)")
    base = ["slam-eval", "--sequence", str(sequence), "--gt-instances", "--engine", "dense",
            "--gt-dropout", "0.2:3", "--track", "--quiet", "--json"]  # fmt: skip
    assert main([*base, "--modes", "raw,seg", "--out", str(tmp_path / "e")]) == 0
    rows = {r["condition"]: r for r in json.loads(capsys.readouterr().out)}
    assert "seg (gt instances, dropout 0.2:3, tracked)" in rows
    assert main([*base, "--modes", "seg", "--sweep", "dilation_px=0,5",
                 "--out", str(tmp_path / "s")]) == 0  # fmt: skip
    capsys.readouterr()
    text = (tmp_path / "s" / "sweep.md").read_text()
    assert "track stage: coast preset" in text and "dropout 0.2 in bursts of 3" in text
    # the stage's knobs sweep like the masking settings
    assert main([*base, "--modes", "seg", "--sweep", "max_coast=0,1",
                 "--out", str(tmp_path / "k")]) == 0  # fmt: skip
    rows = {r["condition"]: r for r in json.loads(capsys.readouterr().out)}
    assert {"max_coast=0", "max_coast=1"} <= set(rows)
    assert rows["max_coast=0"]["recall"] < rows["base (slimseg)"]["recall"]
    no_track = [a for a in base if a != "--track"]
    assert main([*no_track, "--modes", "seg", "--sweep", "max_coast=0,1",
                 "--out", str(tmp_path / "n")]) != 0  # fmt: skip
    assert "add --track" in capsys.readouterr().err
