"""slam-eval --sweep: parsing and validation, the detection cache (one model call per frame,
exact filtering), atomic outputs, the named masking presets and the export metadata, and a
tiny end-to-end sweep on the dense engine."""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from slimseg.cli.main import main
from slimseg.cli.settings_args import add_settings_args, settings_from_args
from slimseg.data.synth import generate
from slimseg.data.tum import TumSequence
from slimseg.deploy.metadata import (
    build_metadata,
    input_dilation_px,
    masking_from_metadata,
)
from slimseg.detections import Prediction
from slimseg.dynamic.epipolar import OrbFeatures
from slimseg.dynamic.mask_patch import pack_masks
from slimseg.dynamic.masking_settings import (
    DEFAULT,
    PAPERS,
    PRESETS,
    SLIMSEG,
    SettingsError,
    preset,
)
from slimseg.objects import Objects
from slimseg.ops.nms import PREDICT_CONF, non_max_suppression
from slimseg.sequence.detection_cache import CachedFrame, build_cache, mask_with
from slimseg.slam.sweep import (
    SweepError,
    check_mode,
    parse_sweep,
    slice_through,
    sweep_points,
)
from slimseg.utils.outputs import MANIFEST

pytest.importorskip("evo", reason="the [slam] extra (make test installs it)")


# ---------------------------------------------------------------- parsing and validation


def test_parse_sweep_values_and_order() -> None:
    spec = parse_sweep(["dilation_px=0,5,11", "conf=0.1, 0.05,0.1", "frame_ratio=0.2"])
    assert list(spec) == ["dilation_px", "conf", "frame_ratio"]
    assert spec["dilation_px"] == (0, 5, 11) and all(
        isinstance(v, int) for v in spec["dilation_px"]
    )
    assert spec["conf"] == (0.1, 0.05)  # duplicates dropped, order kept


@pytest.mark.parametrize(
    ("items", "match"),
    [
        (["speed=1"], "unknown key 'speed'; valid: conf, dilation"),
        (["conf"], "expected KEY=v1,v2"),
        (["conf="], "no values after"),
        (["conf=0.1,abc"], "'abc': not a number"),
        (["dilation_px=2.5"], "'2.5': not a whole number"),
        (["conf=1.5"], "conf = 1.5: expected 0 <= x < 1"),
        (["conf=1"], "conf = 1.0"),
        (["conf=-0.1"], "conf = -0.1"),
        (["t_o=-0.1"], "t_o = -0.1"),
        (["m_th_step=0"], "m_th_step = 0.0"),
        (["conf=0.1", "conf=0.2"], "given twice"),
        ([], "nothing to sweep"),
    ],
)
def test_parse_sweep_errors(items: list[str], match: str) -> None:
    with pytest.raises(SweepError, match=match):
        parse_sweep(items)


def test_keys_that_cannot_act_in_a_mode_are_refused() -> None:
    with pytest.raises(SweepError, match="t_o: has no effect in mode seg"):
        check_mode(parse_sweep(["t_o=0.1,0.4"]), "seg", gt_instances=False)
    with pytest.raises(SweepError, match="all score 1"):
        check_mode(parse_sweep(["conf=0.1"]), "fusion", gt_instances=True)
    check_mode(parse_sweep(["t_o=0.1", "conf=0.1"]), "fusion", gt_instances=False)


def test_cli_errors_are_one_line(tmp_path: Path, capsys) -> None:
    base = ["slam-eval", "--sequence", str(tmp_path), "--out", str(tmp_path / "o"),
            "--gt-instances", "--engine", "dense"]  # fmt: skip
    cases = [
        (["--sweep", "bogus=1"], "unknown key 'bogus'"),
        (["--sweep", "dilation_px=x"], "'x': not a whole number"),
        (["--sweep", "dilation_px=1", "--modes", "seg,fusion"], "exactly one mask mode"),
        (["--sweep", "dilation_px=1", "--modes", "oracle"], "a sweep takes one mask mode"),
        (["--sweep", "dilation_px=1", "--restore"], "--restore is not swept"),
        (["--set", "conf=2"], "setting conf = 2.0"),
        (["--sequence", str(tmp_path)], "several --sequence values need --sweep"),
    ]
    for extra, match in cases:
        assert main([*base, *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and match in err[0], (extra, err)
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------ sweep points


def test_oneway_and_grid_points() -> None:
    spec_items = ["conf=0.05,0.1,0.25", "dilation_px=0,5"]
    spec = parse_sweep(spec_items)
    one = sweep_points(SLIMSEG, spec, "oneway")
    assert one[0].label == "base (slimseg)" and one[0].settings == SLIMSEG
    labels = [p.label for p in one]
    # conf 0.1 and dilation 5 are the base's own values: not repeated
    assert labels[1:4] == ["conf=0.05", "conf=0.25", "dilation_px=0"]
    assert len({p.settings for p in one}) == len(one)
    refs = [p for p in one if p.reference]
    assert [p.label for p in refs] == ["preset papers"] and refs[0].settings == PAPERS
    grid = sweep_points(SLIMSEG, spec, "grid")
    assert len([p for p in grid if not p.reference]) == 3 * 2
    assert "preset papers" in [p.label for p in grid]  # papers' rule, t_o, cut: no point
    more = [*spec_items, "rule=eq1,degrade", "t_o=0.25,1", "cut_behind_m=0,0.5", "motion_odds=1,10",
            "motion_layer_px=0,100", "still_frames=0,20"]  # fmt: skip
    every = sweep_points(SLIMSEG, parse_sweep(more), "grid")
    assert len([p for p in every if not p.reference]) == 3 * 2 * 2 * 2 * 2 * 2 * 2 * 2
    # conf 0.25, dilation 0, rule eq1, t_o 0.25, no cut, odds 1, no motion layer, no stillness
    # test is a point: papers is not added
    assert "preset papers" not in [p.label for p in every]
    curve = slice_through(grid, "conf", grid[0])
    assert [p.settings.conf for p in curve] == [0.05, 0.1, 0.25]
    assert all(p.settings.dilation_px == SLIMSEG.dilation_px for p in curve)
    with pytest.raises(SweepError, match="sweep-mode"):
        sweep_points(SLIMSEG, spec, "random")
    # ground-truth instances all score 1: conf makes no setting of its own
    gti = sweep_points(PAPERS.with_values(conf=0.1, dilation_px=5),
                       parse_sweep(["dilation_px=0,9"]), ignore_conf=True)  # fmt: skip
    assert [p.label for p in gti][1:3] == ["dilation_px=0 (= preset papers)", "dilation_px=9"]
    assert "preset papers" not in [p.label for p in gti]


# ---------------------------------------------------------------------- detection cache


def test_filtering_after_nms_equals_nms_at_the_higher_threshold() -> None:
    """The cache's premise: NMS at a low threshold, then dropping scores <= c, keeps exactly
    what NMS at c keeps (greedy NMS only lets higher scores suppress lower ones)."""
    g = torch.Generator().manual_seed(0)
    nc, a = 3, 400
    xy = torch.rand(1, 2, a, generator=g) * 200
    wh = torch.rand(1, 2, a, generator=g) * 60 + 5
    scores = torch.rand(1, nc, a, generator=g) ** 3
    pred = torch.cat((xy, wh, scores), 1)
    low = non_max_suppression(pred, nc, conf=0.02, max_det=300)[0]
    for c in (0.05, 0.1, 0.25, 0.5):
        high = non_max_suppression(pred, nc, conf=c, max_det=300)[0]
        keep = low.scores > c
        assert torch.equal(low.boxes[keep], high.boxes) and torch.equal(low.classes[keep],
                                                                        high.classes)  # fmt: skip


def _cached(objects: Objects) -> CachedFrame:
    """``objects`` as a sweep's cache keeps them (masks as crops)."""
    feats = OrbFeatures(np.zeros((0, 2), np.float32), np.zeros((0, 32), np.uint8))
    return CachedFrame(0.0, feats, replace(objects, masks=None), pack_masks(objects.masks),
                       None, 0.0, 0.0)  # fmt: skip


def test_cached_masks_round_trip() -> None:
    rng = np.random.default_rng(1)
    masks = np.zeros((3, 30, 40), bool)
    masks[0, 5:12, 7:20] = rng.random((7, 13)) > 0.3
    masks[1, 20:30, 30:40] = True  # touches the bottom-right corner
    frame = _cached(Objects(np.zeros((3, 4)), [0.9, 0.4, 0.05], [0, 1, 0], masks, (30, 40)))
    back = frame.above(0.01)
    assert np.array_equal(back.masks, masks) and back.classes.tolist() == [0, 1, 0]
    back = frame.above(0.3)
    assert np.array_equal(back.masks, masks[:2]) and back.classes.tolist() == [0, 1]
    assert frame.above(0.95).masks.shape == (0, 30, 40)
    none = _cached(Objects(np.zeros((1, 4)), [0.5], [0], None, (30, 40)))
    assert none.above(0.1).masks is None


class CountingPredictor:
    """A stand-in model: one detection per walker of the frame's ground-truth instances with
    score 0.6, and a false detection (score 0.08) on the left tenth of the frame; counts calls
    and the thresholds it was called with."""

    def __init__(self, sequence: Path) -> None:
        from slimseg.dynamic.annotations import AnnotationInstances

        self.truth = AnnotationInstances(sequence)
        self.mobility = self.truth.mobility
        self.stamps = [t for (t, _), _ in TumSequence(sequence).frames]  # called in this order
        self.calls: list[float] = []

    def predict(self, rgb: np.ndarray, conf: float) -> Prediction:
        stamp = self.stamps[len(self.calls)]
        self.calls.append(conf)
        gt = self.truth.for_stamp(stamp)
        h, w = rgb.shape[:2]
        person = gt.classes == 0
        fake = np.zeros((1, h, w), bool)
        fake[0, :, : w // 10] = True
        boxes = np.vstack([gt.boxes[person], [[0, 0, w // 10, h]]]).astype(np.float32)
        scores = np.r_[np.full(person.sum(), 0.6), 0.08].astype(np.float32)
        keep = scores > conf
        return Prediction(boxes=boxes[keep], scores=scores[keep],
                          classes=np.r_[gt.classes[person], 0][keep],
                          names=["person"] * int(keep.sum()), mobility=[1.0] * int(keep.sum()),
                          masks=np.concatenate([gt.masks[person], fake])[keep],
                          image_hw=(h, w))  # fmt: skip


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sweep") / "data"
    generate(out, 1, 1, 64, 3, sequences=1, frames=36, seq_size=(320, 240), progress=False,
             preset="walking_xyz")  # fmt: skip
    return out / "sequences" / "seq_000"


def test_model_runs_once_per_frame_across_a_conf_sweep(seq: Path, tmp_path, monkeypatch, capsys):
    import slimseg.slam.sweep_run as sweep_run

    stand_in = CountingPredictor(seq)
    monkeypatch.setattr(sweep_run, "make_predictor", lambda *a, **k: stand_in)
    args = ["slam-eval", "--sequence", str(seq), "--model", "stand-in.onnx", "--engine",
            "dense", "--modes", "seg", "--preset", "papers", "--sweep", "conf=0.05,0.1",
            "--out", str(tmp_path / "o"), "--quiet", "--json"]  # fmt: skip
    assert main(args) == 0
    n = len(TumSequence(seq))
    # once per frame, at the lowest threshold of the sweep (its points and the presets)
    assert stand_in.calls == [min(0.05, SLIMSEG.conf)] * n
    rows = {r["condition"]: r for r in json.loads(capsys.readouterr().out)}
    # the false detection (0.08) is kept at conf 0.05 only: worse precision, no lost recall
    assert rows["conf=0.05"]["precision"] < rows["conf=0.1"]["precision"]
    assert rows["conf=0.05"]["recall"] >= rows["conf=0.1"]["recall"]
    assert rows["base (papers)"]["precision"] == pytest.approx(rows["conf=0.1"]["precision"])
    assert rows["base (papers)"]["masking_ms"] > rows["base (papers)"]["model_ms"]


def test_cached_masks_equal_a_direct_run(seq: Path, tmp_path: Path) -> None:
    """mask_with on the cache writes what slimseg dynamic writes for the same settings."""
    import cv2

    from slimseg.dynamic.chain_config import ChainConfig
    from slimseg.sequence.sequence_run import run_sequence

    settings = PAPERS.with_values(conf=0.1, dilation_px=3, t_o=0.4)
    direct = run_sequence(
        CountingPredictor(seq),
        seq,
        tmp_path / "d",
        ChainConfig(mode="fusion", masking=settings),
        progress=False,
    )
    cache = build_cache(CountingPredictor(seq), TumSequence(seq), 0.05, progress=False)
    sm = mask_with(cache, "fusion", settings, tmp_path / "c")
    for name in sorted(p.name for p in (tmp_path / "d" / "masks").iterdir()):
        a = cv2.imread(str(tmp_path / "d" / "masks" / name), cv2.IMREAD_GRAYSCALE)
        b = cv2.imread(str(tmp_path / "c" / name), cv2.IMREAD_GRAYSCALE)
        assert np.array_equal(a, b), name
    s = direct.scores["fusion"]
    assert (sm.score.tp, sm.score.fp, sm.score.fn) == (s.tp, s.fp, s.fn)


# ------------------------------------------------------------------------------ outputs


def test_outputs_are_atomic(seq: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    from matplotlib.figure import Figure

    def broken(self, *a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(Figure, "savefig", broken)
    out = tmp_path / "o"
    args = ["slam-eval", "--sequence", str(seq), "--gt-instances", "--engine", "dense",
            "--sweep", "dilation_px=0", "--out", str(out), "--quiet"]  # fmt: skip
    assert main(args) == 2  # an OSError is one line, exit 2, like any bad path
    assert capsys.readouterr().err.strip().endswith("error: disk full")
    left = sorted(p.name for p in out.iterdir())
    stray = [n for n in left if n.startswith("sweep") or n.startswith(".")]
    assert stray == [MANIFEST], left  # the manifest lists what the sweep writes, before it does


@pytest.mark.slow
def test_tiny_sweep_end_to_end(seq: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "o"
    args = ["slam-eval", "--sequence", str(seq), "--gt-instances", "--engine", "dense",
            "--modes", "seg", "--preset", "papers", "--sweep", "dilation_px=3,9", "--sweep",
            "m_th_start=0.6", "--sweep", "m_th_step=0.2", "--out", str(out), "--quiet",
            "--json"]  # fmt: skip
    assert main(args) == 0
    rows = {r["condition"]: r for r in json.loads(capsys.readouterr().out)}
    spec = parse_sweep(["dilation_px=3,9", "m_th_start=0.6", "m_th_step=0.2"])
    assert list(rows) == ["raw", "gt"] + [p.label for p in sweep_points(PAPERS, spec)]
    assert rows["gt"]["ate_rmse"] < rows["raw"]["ate_rmse"]
    assert rows["dilation_px=9"]["dilation_px"] == 9 and rows["m_th_start=0.6"]["m_th_start"] == 0.6
    # seg masks only grow with the dilation: every dynamic keypoint stays found
    assert rows["dilation_px=9"]["recall"] >= rows["dilation_px=3"]["recall"] >= rows[
        "base (papers)"]["recall"]  # fmt: skip
    # above 0.5, Eq. 1 no longer drops points on the static bottles (mobility 0.5)
    assert rows["m_th_start=0.6"]["fp"] <= rows["base (papers)"]["fp"]
    # Eq. 1 never has to raise m_th here (plenty of static points): the step changes no mask,
    # so that setting shares the base's runs instead of adding ORB-SLAM3 noise of its own
    step = rows["m_th_step=0.2"]
    assert step["same_masks_as"] == "base (papers)" and "masks = base (papers)'s" in step["status"]
    assert step["ate_rmse"] == rows["base (papers)"]["ate_rmse"]
    ran = (out / "seq_000" / "runs.csv").read_text()
    assert "m_th_step=0.2" not in ran and "dilation_px=9" in ran
    md = (out / "sweep.md").read_text()
    assert "## seq_000" in md and "| dilation_px=9 " in md
    assert "base settings: papers preset (conf 0.25" in md
    assert (out / "sweep.png").stat().st_size > 10_000
    assert (out / "seq_000" / "runs.csv").is_file()
    masks = list((out / "seq_000" / "masks" / "dilation_px_9").glob("*.png"))
    assert len(masks) == len(TumSequence(seq))


# ----------------------------------------------------------------- presets and metadata


def test_presets_reach_the_cli_and_the_metadata() -> None:
    p = argparse.ArgumentParser()
    add_settings_args(p)

    def masking_from_args(args: argparse.Namespace):
        return settings_from_args(args)[0]

    assert masking_from_args(p.parse_args([])) == DEFAULT == PRESETS["slimseg"]
    assert masking_from_args(p.parse_args(["--preset", "papers"])) == PAPERS
    over = masking_from_args(p.parse_args(["--preset", "papers", "--set", "dilation_px=7"]))
    assert over == PAPERS.with_values(dilation_px=7)
    with pytest.raises(SettingsError, match="unknown masking preset"):
        preset("fast")
    import slimseg

    model = slimseg.build_model("yolov8n-seg", num_classes=2)
    meta = build_metadata(model, ["person", "chair"], [1.0, 0.25], (320, 320))
    entry = meta["slam_masking"]
    assert entry["preset"] == "slimseg" and entry["presets"]["papers"] == PAPERS.as_dict()
    assert masking_from_metadata(meta) == DEFAULT
    assert meta["mobility_threshold"] == DEFAULT.m_th_start
    # the old key, in input pixels: the same frame dilation through CONTRACT.md's formula
    assert meta["recommended_mask_dilation_px"] == input_dilation_px(DEFAULT.dilation_px,
                                                                      (320, 320))  # fmt: skip
    assert meta["recommended_mask_dilation_px"] * 640 / 320 == DEFAULT.dilation_px
    # detection-style thresholds stay their own family
    assert meta["nms"]["conf"] == PREDICT_CONF
    # an export made before slam_masking: the papers' values with its own two keys
    old = {"imgsz": [640, 640], "mobility_threshold": 0.25, "recommended_mask_dilation_px": 5}
    assert masking_from_metadata(old) == PAPERS.with_values(dilation_px=5)
    assert masking_from_metadata({"imgsz": [640, 640]}) == PAPERS


def test_sequence_labels_are_short_and_unique(tmp_path: Path) -> None:
    from slimseg.slam.sweep_run import sequence_labels

    def seq(*parts: str) -> TumSequence:
        folder = tmp_path.joinpath(*parts)
        folder.mkdir(parents=True)
        (folder / "rgb.txt").write_text("1.0 rgb/1.png\n")
        (folder / "depth.txt").write_text("1.0 depth/1.png\n")
        return TumSequence(folder)

    a, b, c = seq("xyz", "seq_000"), seq("static", "seq_000"), seq("walking_rpy")
    assert sequence_labels([a, b]) == ["xyz_seq_000", "static_seq_000"]
    assert sequence_labels([c]) == ["walking_rpy"]
