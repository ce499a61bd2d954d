"""`slimseg calibrate`: the search space from the registry, the hand-checked objective, the
reserved sequences, the choice after the ORB-SLAM3 confirmation, the calibrated export and
its use by default (dynamic, slam-eval's settings, Masker), and the CLI's refusals."""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from conftest import open_class_bias

import slimseg
from slimseg.calibrate.confirm import Ate, choose
from slimseg.calibrate.objective import (
    EARN_SE,
    RECALL_FLOOR,
    RECALL_WEIGHT,
    CellScore,
    Evaluation,
)
from slimseg.calibrate.run import DEFAULT_SEQUENCES
from slimseg.calibrate.search import (
    PERTURBED_KNOBS,
    SEARCHED,
    Trial,
    best,
    clipped,
    moved,
    moved_keys,
    nearby,
    preferred,
    run_search,
)
from slimseg.calibrate.sequences import CALIBRATION_PRESETS
from slimseg.cli.main import main
from slimseg.data.synth.sequence import write_sequence
from slimseg.data.synth.world_frames import FIRST_INDEX, MAX_EVAL_SEQUENCES
from slimseg.data.tum import TumSequence
from slimseg.deploy.calibrated import (
    CALIBRATED,
    expectation,
    is_calibrated,
    model_masking,
    read_model_metadata,
    write_calibrated,
)
from slimseg.deploy.metadata import masking_from_metadata
from slimseg.deploy.onnx_export import export_onnx
from slimseg.deploy.predictor import Predictor
from slimseg.dynamic.annotations import AnnotationInstances, Dropout
from slimseg.dynamic.knobs import BY_KEY, KNOBS
from slimseg.dynamic.masking_settings import DEFAULT, PAPERS
from slimseg.models.batchnorm_stats import batchnorm_from
from slimseg.sequence.detection_cache import build_cache
from slimseg.sequence.sequence_report import ModeScore, truth_regions

NAMES = ["person", "chair"]


def test_search_space_is_the_registry_s() -> None:
    """Every masking knob but none of the track stage's is searched, inside its valid range;
    the presets are points of the space."""
    assert {k.key for k in SEARCHED} == {k.key for k in KNOBS if k.group == "masking"}
    for k in SEARCHED:
        if k.choices:
            continue
        lo, hi = k.search
        assert lo < hi, k.key
        k.check(k.kind(lo)), k.check(k.kind(hi))
        assert not k.log or lo > 0, k.key
    for preset in (DEFAULT, PAPERS):
        values = clipped(preset.as_dict())
        assert preset.with_values(**values) == preset  # the presets lie inside the spans


def test_objective_by_hand() -> None:
    """Mean precision minus 5 x the summed shortfalls below 95 % + 2 % margin, the lower of
    keypoint and walker recall deciding each cell's shortfall."""
    assert round(RECALL_FLOOR, 6) == 0.97 and RECALL_WEIGHT == 5.0
    met = CellScore("a", "per_frame", 0.6, 0.98, 1.0)
    short = CellScore("a", "track", 0.8, 0.90, 1.0)
    assert met.value() == pytest.approx(0.6)
    assert short.value() == pytest.approx(0.8 - 5 * 0.07)
    lost = CellScore("a", "track", 0.8, 0.99, 1.0, walker_recall=0.87)  # a walker-frame lost
    assert lost.shortfall() == pytest.approx(0.10)
    nothing = CellScore("b", "track", float("nan"), 0.0, 1.0)  # nothing masked on walkers
    assert nothing.value() == pytest.approx(-5 * 0.97)
    no_walkers = CellScore("c", "track", 0.0, float("nan"), 1.0)
    assert no_walkers.value() == 0.0
    ev = Evaluation(DEFAULT, (met, short))
    assert ev.value() == pytest.approx((0.6 + 0.8) / 2 - 5 * 0.07)
    # one walker missed on one of many cells costs its whole shortfall, not a share of it
    many = Evaluation(DEFAULT, (short,) + (met,) * 7)
    assert many.value() == pytest.approx((0.8 + 7 * 0.6) / 8 - 5 * 0.07)
    assert not ev.floor_met() and Evaluation(DEFAULT, (met,)).floor_met()
    assert ev.pooled("track") == (pytest.approx(0.8), pytest.approx(0.9))


def test_earned_by_hand() -> None:
    """A candidate earns its mean paired per-cell gain over the shipped preset less one
    standard error: a gain the cells agree on beats an equal mean gain one cell carries; a
    recall shortfall enters a cell at the objective's weight times the number of cells."""
    assert EARN_SE == 1.0

    def ev(*cells: tuple[float, float]) -> Evaluation:
        return Evaluation(DEFAULT, tuple(CellScore(f"s{i}", "per_frame", p, r, 1.0)
                                         for i, (p, r) in enumerate(cells)))  # fmt: skip

    shipped = ev((0.5, 0.98), (0.5, 0.98), (0.5, 0.98))
    assert shipped.earned(shipped) == 0.0
    even = ev((0.6, 0.98), (0.6, 0.98), (0.6, 0.98))  # +0.1 on each: no spread
    assert even.earned(shipped) == pytest.approx(0.1)
    lopsided = ev((0.8, 0.98), (0.5, 0.98), (0.5, 0.98))  # gains +0.3, 0, 0: mean 0.1
    se = math.sqrt(((0.2**2) + 2 * (0.1**2)) / 2 / 3)
    assert lopsided.earned(shipped) == pytest.approx(0.1 - se)
    assert lopsided.value() == pytest.approx(even.value())  # the objective cannot tell them
    short = ev((0.9, 0.95), (0.9, 0.98), (0.9, 0.98))  # 2 recall points short on one cell
    assert short.contributions()[0] == pytest.approx(0.9 - 5 * 3 * 0.02)
    assert sum(short.contributions()) / 3 == pytest.approx(short.value())
    assert lopsided.gain(shipped) == (pytest.approx(0.1), pytest.approx(se))
    with pytest.raises(ValueError, match="different cells"):
        ev((0.5, 0.98)).earned(shipped)


def test_preferred_is_the_one_standard_error_rule() -> None:
    """Candidates that earn something come first; among those whose mean gain is within one
    standard error of the best mean gain, the fewest knobs moved; the shipped preset last."""

    def trial(n: int, gains: tuple[float, ...], **moved: object) -> Trial:
        cells = tuple(CellScore(f"s{i}", "per_frame", 0.5 + g, 0.98, 1.0)
                      for i, g in enumerate(gains))  # fmt: skip
        return Trial(n, "search", Evaluation(DEFAULT.with_values(**moved), cells), 0.0)

    shipped = dataclasses.replace(trial(0, (0.0, 0.0, 0.0)), origin="slimseg")
    wide = trial(1, (0.30, 0.10, 0.20), conf=0.3, dilation_px=9, t_o=0.5)  # mean 0.2, SE .058
    near = trial(2, (0.18, 0.14, 0.16), conf=0.2)  # mean 0.16: within one SE of wide's
    far = trial(3, (0.05, 0.05, 0.05), dilation_px=2)  # earns, but far below
    worse = trial(4, (0.2, -0.3, 0.0), dilation_px=3)  # mean < 0: earns nothing
    inert = trial(5, (0.19, 0.15, 0.17), m_th_step=0.2)  # acts under eq1 only: moves 0
    order = preferred([shipped, wide, near, far, worse, inert], shipped)
    assert [t.number for t in order] == [5, 2, 1, 3, 0]
    assert moved(inert, shipped) == 0 and moved(wide, shipped) == 3
    # the report names the same knobs the rule counts: the inert one is not among them
    assert moved_keys(inert, shipped) == [] and moved_keys(wide, shipped) == [
        "conf", "dilation_px", "t_o"]  # fmt: skip
    assert best([shipped, wide, near, far]).number == 2
    assert preferred([shipped, worse], shipped) == [shipped]


def test_nearby_moves_a_few_knobs() -> None:
    """The search's start: the shipped preset with PERTURBED_KNOBS knobs drawn anew, each
    value valid for its knob and inside its span, each knob one that acts under the rule."""
    import random

    rng = random.Random(0)
    base = clipped(DEFAULT.as_dict())
    for _ in range(200):
        near = nearby(rng, DEFAULT.as_dict())
        moved = [k for k in SEARCHED if near[k.key] != base[k.key]]
        assert 1 <= len(moved) <= PERTURBED_KNOBS
        for k in moved:
            assert k.rule is None or k.rule == near["rule"], k.key  # it acts
            k.check(near[k.key])
            assert type(near[k.key]) is type(base[k.key]), k.key
            assert k.choices or k.search[0] <= near[k.key] <= k.search[1], k.key
    assert DEFAULT.with_values(**near)  # a valid setting


def test_walker_frames_by_hand() -> None:
    """Ground-truth regions stand in for walkers: one with under a fifth of its keypoints
    flagged is lost in that frame; a region with under 8 keypoints does not count."""
    truth = np.zeros((20, 40), bool)
    truth[2:10, 2:10] = truth[2:10, 20:30] = truth[14:18, 2:6] = True
    left = [[x, y] for x in range(3, 9) for y in (3, 5)]  # 12 keypoints
    right = [[x, 4] for x in range(21, 29)]  # 8
    sliver = [[3, 15], [4, 15]]  # 2: not a walker
    kps = np.array(left + right + sliver + [[35, 15]], float)
    regions = truth_regions(truth, kps)
    assert len(set(regions[:12])) == len(set(regions[12:20])) == 1 and regions[-1] == 0
    dynamic = np.zeros(len(kps), bool)
    dynamic[:3] = True  # 3 / 12 = 25 %: covered
    dynamic[12] = True  # 1 / 8 = 12.5 %: lost
    score = ModeScore()
    score.add_walkers(dynamic, regions)
    assert (score.walkers, score.walkers_missed) == (2, 1)
    assert score.walker_recall == pytest.approx(0.5)
    assert math.isnan(ModeScore().walker_recall)


def test_calibration_sequences_are_reserved() -> None:
    """Their indices are neither training worlds (10,000+, 20,000+) nor evaluation sequences
    (below 10,000) of any seed."""
    first = FIRST_INDEX["calibrate"]
    assert first >= MAX_EVAL_SEQUENCES
    others = [v for k, v in FIRST_INDEX.items() if k != "calibrate"]
    assert all(first >= v + (FIRST_INDEX["val"] - FIRST_INDEX["train"]) for v in others)
    assert set(CALIBRATION_PRESETS) == {"walking_xyz", "walking_halfsphere", "walking_static",
                                        "walking_rpy"}  # fmt: skip
    assert len(CALIBRATION_PRESETS) == DEFAULT_SEQUENCES  # every preset once


def _trial(n: int, value: float) -> Trial:
    cell = CellScore("s", "per_frame", value, 1.0, 1.0)
    return Trial(n, "search", Evaluation(DEFAULT, (cell,)), 0.0)


def test_choice_after_confirmation() -> None:
    """Within the ground-truth masks' run spread the objective decides; beyond it, the
    objective among those no worse than the shipped preset; never one worse than it."""
    truth = Ate("gt", (0.010, 0.012, 0.018), lost=0, frames=60)
    a, b, c, shipped = _trial(0, 0.9), _trial(1, 0.8), _trial(2, 0.7), _trial(3, 0.5)
    ates = {0: Ate("0", (0.03,) * 3, 0, 60), 1: Ate("1", (0.015,) * 3, 0, 60),
            2: Ate("2", (0.011,) * 3, 0, 60), 3: Ate("3", (0.02,) * 3, 0, 60)}  # fmt: skip
    trials = [a, b, c, shipped]
    assert choose(trials, truth, ates, shipped).number == 1  # b, c within; b scores higher
    ates[1] = Ate("1", (0.015,) * 3, lost=5, frames=60)  # loses frames the truth does not
    assert choose(trials, truth, ates, shipped).number == 2
    far = {n: Ate(str(n), (v,) * 3, 0, 60)
           for n, v in ((0, 0.05), (1, 0.04), (2, 0.03), (3, 0.045))}  # fmt: skip
    # none within: a scores best but tracks worse than the shipped preset; b tracks better
    # and scores next; c's lower ATE alone does not decide
    assert choose(trials, truth, far, shipped).number == 1
    # round 4's lenient test: b's median above the shipped preset's median, though within its
    # worst run, no longer passes; c's (below the shipped median) does
    spread = dict(far)
    spread[3] = Ate("3", (0.035, 0.04, 0.05), 0, 60)
    spread[1] = Ate("1", (0.042, 0.045, 0.046), 0, 60)
    spread[2] = Ate("2", (0.03, 0.039, 0.06), 0, 60)
    assert choose(trials, truth, spread, shipped).number == 2
    spread[2] = Ate("2", (0.041,) * 3, 0, 60)
    assert choose(trials, truth, spread, shipped).number == 3  # none at or below 0.04
    worse = {n: Ate(str(n), (v,) * 3, 0, 60) for n, v in ((0, 0.05), (1, 0.06), (2, 0.07))}
    worse[3] = Ate("3", (0.03, 0.035, 0.04), 0, 60)
    assert choose(trials, truth, worse, shipped).number == 3  # every candidate worse


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("calibrate") / "seq"
    write_sequence(root, seed=5, index=FIRST_INDEX["calibrate"], frames=14, size=(320, 240),
                   preset="walking_xyz")  # fmt: skip
    return root


def test_search_on_ground_truth_instances(sequence: Path) -> None:
    """The presets come first, every candidate is scored in both conditions, the best is at
    least the shipped preset's; the worker processes score as the process itself does."""
    seq = TumSequence(sequence)
    source = AnnotationInstances(sequence, Dropout(0.3, 2, seed=1))
    caches = {"s": build_cache(source, seq, 0.0, progress=False)}
    one = run_search(caches, DEFAULT, 1e9, 5, workers=1, seed=3)
    assert [t.origin for t in one] == ["slimseg", "papers", "near", "near", "near"]
    shipped_values = clipped(DEFAULT.as_dict())
    for t in one[2:]:  # the start: the shipped preset with a few knobs moved
        values = clipped(t.evaluation.settings.as_dict())
        assert 0 < sum(values[k] != v for k, v in shipped_values.items()) <= PERTURBED_KNOBS
    assert all(len(t.evaluation.cells) == 2 for t in one)
    shipped = one[0]
    assert best(one).earned(shipped) >= shipped.earned(shipped) == 0.0
    dropped = shipped.evaluation.cells[0]  # per frame: 30 % of the instances dropped
    assert 0.0 < dropped.walker_recall < 1.0
    two = run_search(caches, DEFAULT, 1e9, 3, workers=2, seed=3)
    by_origin = {t.origin: t.value for t in two if t.origin != "search"}
    assert by_origin["slimseg"] == pytest.approx(shipped.value)
    assert by_origin["papers"] == pytest.approx(one[1].value)


@pytest.fixture(scope="module")
def model(sequence: Path) -> Path:
    """yolov8n-seg at 64 px, BatchNorm statistics of the sequence's frames, a few scores above
    the masking threshold; slimseg's metadata."""
    torch.manual_seed(0)
    net = slimseg.build_model("yolov8n-seg", num_classes=len(NAMES))
    seq = TumSequence(sequence)
    frames = np.stack([cv2.resize(seq.load(i)[0], (64, 64)) for i in range(0, 14, 3)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        batchnorm_from(net, torch.from_numpy(frames).permute(0, 3, 1, 2).float() / 255)
        open_class_bias(net)
        out = sequence.parent / "m.onnx"
        export_onnx(net, out, (64, 64), NAMES, [1.0, 0.0], simplify=False)
    return out


def test_calibrated_export_is_the_default(model: Path, sequence: Path, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """A calibrated copy carries its preset beside the shipped ones; dynamic uses it without a
    note, the uncalibrated model with one; Masker takes it by default."""
    settings = DEFAULT.with_values(conf=0.3, dilation_px=7)
    out = write_calibrated(model, tmp_path / "cal.onnx", settings, {"report_digest": "x"})
    meta = read_model_metadata(out)
    assert is_calibrated(meta) and not is_calibrated(read_model_metadata(model))
    assert set(meta["slam_masking"]["presets"]) == {"papers", "slimseg", CALIBRATED}
    assert model_masking(meta, out) == (settings, None)
    assert json.loads((tmp_path / "cal.json").read_text())["slam_masking"]["preset"] == CALIBRATED
    masker = slimseg.Masker.from_predictor(Predictor.from_path(out))
    assert masker.config.masking == settings
    for onnx, noted in ((out, False), (model, True)):
        argv = ["dynamic", "--sequence", str(sequence), "--model", str(onnx), "--out",
                str(tmp_path / f"d_{onnx.stem}"), "--quiet"]  # fmt: skip
        assert main(argv) == 0
        cap = capsys.readouterr()
        assert ("no calibrated masking preset" in cap.err) is noted
        if not noted:
            assert "calibrated preset of cal.onnx (conf 0.3, dilation_px 7" in cap.out
    argv = ["dynamic", "--sequence", str(sequence), "--model", str(model), "--preset",
            CALIBRATED, "--out", str(tmp_path / "d_refused")]  # fmt: skip
    assert main(argv) == 2
    assert "--preset calibrated" in capsys.readouterr().err


def test_calibrate_cli(model: Path, sequence: Path, tmp_path: Path,
                       capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The command end to end without the ORB-SLAM3 confirmation: report files, the chosen
    settings in the copy, the report's digest in its metadata; the model left as it was."""
    pytest.importorskip("optuna")
    before = model.read_bytes()
    out = tmp_path / "m_cal.onnx"
    argv = ["calibrate", "--model", str(model), "--out", str(out), "--sequence", str(sequence),
            "--confirm-runs", "0", "--trials", "4", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    assert model.read_bytes() == before
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert line.startswith("calibrated m.onnx") and "4 candidates" in line, line
    folder = tmp_path / "m_cal_calibration"
    report = json.loads((folder / "report.json").read_text())
    assert len(report["trials"]) == 4 and report["confirmation"] is None
    chosen = report["trials"][[t["number"] for t in report["trials"]].index(report["chosen"])]
    assert chosen["objective"] == max(t["objective"] for t in report["trials"])
    png = cv2.imread(str(folder / "report.png"))
    assert png is not None and png.shape[1] > 1000 and png.std() > 10
    meta = read_model_metadata(out)
    entry = meta["slam_masking"]
    assert entry["presets"][CALIBRATED] == report["settings"]
    assert entry["calibration"]["report_digest"].startswith("sha256:")
    assert entry["calibration"]["on"] == {"sequences": ["seq"]}
    expect = entry["calibration"]["expect"]
    assert 0 <= expect["mask_share"] <= 1 and 0 <= expect["static_share"] <= 1
    settings = masking_from_metadata(meta, CALIBRATED)
    assert expectation(meta, settings).mask_share == expect["mask_share"]
    assert expectation(meta, DEFAULT.with_values(conf=0.49)) is None  # a user's own choice
    for key, value in report["settings"].items():
        BY_KEY[key].check(value)
        assert not isinstance(value, float) or float(f"{value:.3g}") == value, (key, value)
    assert not math.isnan(chosen["objective"])


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--out", "{model}"], "is the --model itself"),
        (["--out", "{tmp}/x.txt"], "ending in .onnx"),
        (["--out", "{tmp}/foreign.onnx"], "foreign.onnx"),
        (["--out", "{tmp}/y.onnx", "--budget", "0"], "--budget 0"),
        (["--out", "{tmp}/z.onnx", "--sequence", "{tmp}"], "no dynamic/ folder"),
    ],
)
def test_calibrate_refuses(model: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                           extra: list[str], message: str) -> None:  # fmt: skip
    """One line naming the option, exit 2, nothing written."""
    pytest.importorskip("optuna")
    (tmp_path / "foreign.onnx").write_bytes(b"a user's file")
    args = [a.format(model=model, tmp=tmp_path) for a in extra]
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["calibrate", "--model", str(model), "--confirm-runs", "0", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert (tmp_path / "foreign.onnx").read_bytes() == b"a user's file"


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--end2end", "--calibrate-masking"], "--calibrate-masking calibrates a raw"),
        (["--calibrate-masking", "0"], "--calibrate-masking 0.0: expected seconds > 0"),
    ],
)
def test_export_calibrate_masking_refuses(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          extra: list[str], message: str) -> None:  # fmt: skip
    """export --calibrate-masking: one line before any export work."""
    out = tmp_path / "m.onnx"
    argv = ["export", "--weights", "yolov8n-seg", "--nc", "2", "--imgsz", "64", "--out", str(out)]
    assert main([*argv, *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not out.exists()
