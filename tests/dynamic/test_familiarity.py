"""The chain against its model's calibration: masks far looser than calibrated move every
setting to the tighter of the calibrated and shipped values, once; far tighter, the recall
knobs to the looser."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from slimseg.dynamic.familiarity import WINDOW, Expectation, Familiarity, looser, tighter
from slimseg.dynamic.masking_settings import DEFAULT, PAPERS


def _frames(f: Familiarity, share: float, static: float, n: int = WINDOW) -> list:
    mask = np.zeros((10, 100), np.uint8)
    mask[:, : round(share * 100)] = 255
    dynamic = np.arange(100) >= round(static * 100)
    return [f.observe(mask, dynamic) for _ in range(n)]


def test_tighter_by_hand() -> None:
    loose = DEFAULT.with_values(conf=0.03, dilation_px=12, cut_behind_m=0.0, motion_odds=2.0,
                                min_static=40, keep_score=0.3)  # fmt: skip
    t = tighter(loose, DEFAULT)
    assert (t.conf, t.dilation_px, t.cut_behind_m) == (DEFAULT.conf, DEFAULT.dilation_px, 0.5)
    assert (t.motion_odds, t.min_static, t.keep_score) == (10.0, 100, 0.5)
    assert t.rule == loose.rule and t.t_o == loose.t_o  # untouched knobs stay
    assert tighter(DEFAULT, PAPERS).cut_behind_m == 0.5  # an active cut beats none
    assert tighter(DEFAULT, DEFAULT) == DEFAULT


def test_far_looser_masks_tighten_once(caplog: pytest.LogCaptureFixture) -> None:
    cal = DEFAULT.with_values(conf=0.03, dilation_px=12)
    f = Familiarity(Expectation(0.10, 0.80, DEFAULT), cal)
    with caplog.at_level(logging.WARNING):
        out = _frames(f, share=0.45, static=0.5)
        out += _frames(f, share=0.45, static=0.5)  # judged once only
    assert out[: WINDOW - 1] == [None] * (WINDOW - 1) and out[WINDOW:] == [None] * WINDOW
    assert out[WINDOW - 1] == tighter(cal, DEFAULT) and f.verdict == "looser"
    warned = [r for r in caplog.records if "far looser" in r.getMessage()]
    assert len(warned) == 1 and "45.0 %" in warned[0].getMessage()


@pytest.mark.parametrize(
    ("share", "static", "verdict"),
    [(0.12, 0.8, "familiar"), (0.19, 0.79, "familiar"), (0.01, 0.99, "tighter"),
     (0.10, 0.30, "looser")],
)  # fmt: skip
def test_verdicts(share: float, static: float, verdict: str) -> None:
    cal = DEFAULT.with_values(conf=0.44, dilation_px=2, m_th_start=0.5, cut_behind_m=1.0)
    f = Familiarity(Expectation(0.10, 0.80, DEFAULT), cal)
    out = _frames(f, share, static)
    assert f.verdict == verdict
    assert (out[-1] is not None) == (verdict != "familiar")
    if verdict == "tighter":  # the recall knobs back to the shipped ones
        assert out[-1] == looser(cal, DEFAULT) == cal.with_values(conf=0.1, dilation_px=5,
                                                                   m_th_start=0.25)  # fmt: skip
