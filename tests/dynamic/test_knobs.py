"""The knob registry is the one home of every setting: the settings dataclasses, the CLI, the
sweep keys, the docs table and the C++ header all come from it."""

from __future__ import annotations

import argparse
from dataclasses import fields
from pathlib import Path

import pytest

from slimseg.cli.main import main
from slimseg.cli.settings_args import add_settings_args, settings_from_args
from slimseg.dynamic.knobs import BY_KEY, KNOBS, MASKING_KEYS, TRACK_KEYS, KnobError, knob
from slimseg.dynamic.knobs_render import rendered
from slimseg.dynamic.masking_settings import PAPERS, PRESETS, SLIMSEG, MaskingSettings
from slimseg.dynamic.track_settings import COAST, TrackSettings
from slimseg.slam.sweep import SweepError, check_mode, parse_sweep

ROOT = Path(__file__).resolve().parents[2]


def test_generated_files_are_current() -> None:
    """docs/settings.md and the C++ header equal what the registry renders: after changing a
    knob, run ``python tools/gen_settings.py``."""
    for rel, text in rendered().items():
        assert (ROOT / rel).read_text() == text, f"{rel} is stale: run python tools/gen_settings.py"


def test_every_field_is_a_knob_and_every_knob_a_field() -> None:
    assert tuple(f.name for f in fields(MaskingSettings)) == MASKING_KEYS
    assert tuple(f.name for f in fields(TrackSettings)) == TRACK_KEYS
    for name, s in PRESETS.items():
        assert s.as_dict() == {k: BY_KEY[k].presets[name] for k in MASKING_KEYS}
    assert COAST.as_dict() == {k: BY_KEY[k].presets["coast"] for k in TRACK_KEYS}


def test_levers_take_their_defaults_from_the_registry() -> None:
    from slimseg.dynamic.degrade import KEEP_SCORE
    from slimseg.dynamic.motion_evidence import MOTION_ODDS
    from slimseg.dynamic.seg_box import T_O
    from slimseg.dynamic.threshold import DYNAMIC_FRAME_RATIO, M_TH_START, M_TH_STEP

    levers = (M_TH_START, M_TH_STEP, DYNAMIC_FRAME_RATIO, T_O, KEEP_SCORE)
    papers = (PAPERS.m_th_start, PAPERS.m_th_step, PAPERS.frame_ratio, PAPERS.t_o)
    assert levers == (*papers, PAPERS.keep_score)
    assert SLIMSEG.motion_odds == MOTION_ODDS


@pytest.mark.parametrize("k", KNOBS, ids=lambda k: k.key)
def test_each_knob_refuses_what_is_out_of_its_range(k) -> None:
    for value in k.presets.values():
        k.check(value)
    bad = ["sometimes", "eq2"] if k.choices else [k.high + 1, k.low - 1, True, "1"]
    if k.kind is int and not k.choices:
        bad.append(k.low + 0.5)
    for value in bad:
        with pytest.raises(KnobError, match=k.key):
            k.check(value)


def _parse(argv: list[str]) -> tuple:
    p = argparse.ArgumentParser()
    add_settings_args(p)
    return settings_from_args(p.parse_args(argv))


def test_set_overrides_the_preset_and_a_track_key_turns_the_stage_on(capsys) -> None:
    masking, plan = _parse(["--preset", "papers", "--set", "conf=0.3", "dilation_px=4"])
    assert masking == PAPERS.with_values(conf=0.3, dilation_px=4) and not plan.on
    masking, plan = _parse(["--set", "max_coast=5", "--rate", "3"])
    assert masking == SLIMSEG and plan.settings.max_coast == 5 and plan.rate.every == 3
    _parse(["--set", "m_th_step=0.2"])  # inert under the shipped degrading rule: said so
    assert "m_th_step changes nothing under rule degrade" in capsys.readouterr().err
    with pytest.raises(KnobError, match=r"--set setting conf = 2.0: expected 0 <= x < 1"):
        _parse(["--set", "conf=2"])
    with pytest.raises(KnobError, match="unknown setting 'cut_behind'"):
        _parse(["--set", "cut_behind=0.5"])  # an old sweep key: the one name is the field's


def test_sweep_keys_are_the_knobs() -> None:
    spec = parse_sweep(["dilation_px=0,5", "still_frames=0,20", "rule=eq1,degrade"])
    assert spec == {"dilation_px": (0, 5), "still_frames": (0, 20), "rule": ("eq1", "degrade")}
    with pytest.raises(SweepError, match="whole number"):
        parse_sweep(["dilation_px=2.5"])
    with pytest.raises(SweepError, match="has no effect in mode box"):
        check_mode(parse_sweep(["t_o=0.5"]), "box", False)
    assert knob("t_o").acts_in == knob("frame_ratio").acts_in


def test_dynamic_help_is_a_page(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["dynamic", "--help"])
    text = capsys.readouterr().out
    options = [ln for ln in text.splitlines() if ln.lstrip().startswith("-")]
    assert len(options) <= 30, len(options)
    assert all(f"  {k.key} (" in text for k in KNOBS)  # every key listed in the epilog
