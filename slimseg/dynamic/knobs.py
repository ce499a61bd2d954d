"""Every knob of the masking chain, one home: name, type, range, help, where it acts, what it
needs, and each preset's value.

Everything else is derived from :data:`KNOBS`: the settings' validation
(:mod:`slimseg.dynamic.masking_settings`, :mod:`slimseg.dynamic.track_settings`), the presets,
the CLI's ``--set KEY=VALUE`` and ``slam-eval --sweep KEY=v1,v2`` keys, the settings table of
``docs/settings.md`` and the C++ consumer's defaults and ranges
(``export/cpp/include/slimseg/settings_generated.hpp``; both written by
``tools/gen_settings.py``, and ``tests/dynamic/test_knobs.py`` fails when either is stale). A lever
imports its default from here, never the reverse.

Adding a knob: one :class:`Knob` row below, its field in the settings dataclass (a test checks
that the two agree), the lever that reads it, and ``python tools/gen_settings.py``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import StrEnum

from slimseg.dynamic.modes import EPIPOLAR_MODES, WEIGHED_MODES, Mode
from slimseg.errors import SlimsegError


class Rule(StrEnum):
    """What happens when static support runs short (docs/slam_defaults.md §1): ``eq1`` raises
    Eq. 1's mobility threshold, then gives up the frame (the paper's rule); ``degrade`` gives
    up the least certain masks one at a time (:mod:`slimseg.dynamic.degrade`)."""

    EQ1 = "eq1"
    DEGRADE = "degrade"


class KnobError(SlimsegError):
    """A knob's value out of its range, or an unknown knob (one line naming it)."""


Value = float | int | str

ALL_MODES: tuple[Mode, ...] = tuple(Mode)
RULE_MODES: tuple[Mode, ...] = tuple(m for m in Mode if m != Mode.BOX_DEPTH_RANSAC)
"""Modes that end in Eq. 1 or the degrading rule (depth-RANSAC decides on its own)."""
MASK_MODES: tuple[Mode, ...] = tuple(m for m in RULE_MODES if m != Mode.BOX)
"""Modes with instance masks to cut by depth."""
FUSION_MODES: tuple[Mode, ...] = (Mode.FUSION, Mode.FUSION_EPIPOLAR)
"""Modes with Eq. 3 and Eq. 4."""


@dataclass(frozen=True)
class Knob:
    """One setting: ``key`` (the settings field, the ``--set`` / ``--sweep`` key and the
    metadata key: one name), ``kind`` (int, float or str), its range ``low``-``high``
    (``open_low`` / ``open_high``: that bound excluded) or its ``choices``, ``help``,
    ``acts_in`` (the modes where it changes anything), ``needs`` (what else it needs to act:
    ``depth``, ``camera``, ``history`` (earlier frames), ``track`` (the track stage)),
    ``rule`` (the rule it acts under; None: both), ``group`` (``masking`` or ``track``), the
    value of each preset (``papers`` / ``slimseg``; track knobs: ``coast``) and ``off``, the
    value that switches it off."""

    key: str
    kind: type
    low: float
    high: float
    help: str
    presets: dict[str, Value]
    acts_in: tuple[Mode, ...] = ALL_MODES
    needs: tuple[str, ...] = ()
    rule: Rule | None = None
    group: str = "masking"
    open_low: bool = False
    open_high: bool = False
    choices: tuple[str, ...] = ()
    off: Value | None = None
    """the value that switches the lever off (None: it always acts)"""
    search: tuple[float, float] | None = None
    """the span ``slimseg calibrate`` searches (inside the range; None: not searched; a knob
    with ``choices`` searches them all when this is ``(0, 0)``)"""
    log: bool = False
    """search on a log scale (a span over decades)"""

    def check(self, value: object) -> None:
        """Raise :class:`KnobError` unless ``value`` is valid for this knob."""
        if self.choices:
            if value not in self.choices:
                raise KnobError(f"setting {self.key} = {value!r}: expected one of "
                                f"{', '.join(self.choices)}")  # fmt: skip
            return
        integer = self.kind is int
        typed = isinstance(value, int) if integer else isinstance(value, int | float)
        ok = typed and not isinstance(value, bool) and self.low <= value <= self.high  # type: ignore[operator]
        ok = ok and not (self.open_low and value == self.low)
        if not ok or (self.open_high and value == self.high):
            raise KnobError(f"setting {self.key} = {value!r}: expected {self.describe_range()}")

    def describe_range(self) -> str:
        """``0 <= x < 1``, ``a whole number 0-200``, ``eq1 or degrade``."""
        if self.choices:
            return " or ".join(self.choices)
        lo, hi = f"{self.low:g}", f"{self.high:g}"
        if self.kind is int:
            return f"a whole number {lo}-{hi}"
        return f"{lo} {'<' if self.open_low else '<='} x {'<' if self.open_high else '<='} {hi}"

    def parse(self, text: str) -> Value:
        """``text`` (a CLI value) as this knob's type, checked; :class:`KnobError` otherwise."""
        try:
            value: Value = self.kind(text) if self.kind is not float else float(text)
        except ValueError:
            kind = "a whole number" if self.kind is int else "a number"
            raise KnobError(f"setting {self.key} = {text!r}: not {kind}") from None
        self.check(value)
        return value


def _m(key, kind, low, high, papers, slimseg, help, **kw) -> Knob:
    return Knob(key, kind, low, high, help, {"papers": papers, "slimseg": slimseg}, **kw)


def _t(key, kind, low, high, coast, help, **kw) -> Knob:
    return Knob(key, kind, low, high, help, {"coast": coast}, group="track", needs=("track",),
                **kw)  # fmt: skip


KNOBS: tuple[Knob, ...] = (
    # -- masking (MaskingSettings); papers: the equations as printed, slimseg: chosen from
    # the sweeps of docs/slam_defaults.md
    _m("conf", float, 0.0, 1.0, 0.25, 0.1, "detector score threshold for masking "
       "(not predict's); papers: YOLO's detection-style default", open_high=True,
       search=(0.02, 0.5), log=True),
    _m("dilation_px", int, 0, 200, 0, 5, "px added around every mask before keypoints are "
       "judged (at a 640-px-wide frame; scaled with the frame)", search=(0, 16)),
    _m("min_static", int, 0, 100_000, 100, 100, "Eq. 1: static points needed",
       acts_in=RULE_MODES, search=(20, 400), log=True),
    _m("m_th_start", float, 0.0, 1.0, 0.25, 0.25, "Eq. 1: starting mobility threshold (and "
       "the prior above which a class counts as a mover)", search=(0.1, 0.6)),
    _m("m_th_step", float, 0.0, 1.0, 0.1, 0.1, "Eq. 1: threshold step", acts_in=RULE_MODES,
       rule=Rule.EQ1, open_low=True, search=(0.05, 0.3)),
    _m("frame_ratio", float, 0.0, 1.0, 0.05, 0.05, "Eq. 3: fraction of points on mobile "
       "objects that makes a dynamic keyframe", acts_in=FUSION_MODES, search=(0.01, 0.2)),
    _m("t_o", float, 0.0, 1.0, 0.25, 1.0, "Eq. 4: seg-mask / box coverage above which the seg "
       "mask is kept (slimseg 1 with the depth cut: every box cut to its depth layer)",
       acts_in=FUSION_MODES, search=(0.25, 1.0)),
    _m("rule", str, 0, 0, Rule.EQ1.value, Rule.DEGRADE.value, "when static support runs "
       "short: eq1 (raise the threshold, then give up the frame) or degrade (give up the "
       "least certain masks first)", acts_in=RULE_MODES, choices=tuple(r.value for r in Rule),
       search=(0, 0)),
    _m("keep_score", float, 0.0, 1.0, 0.5, 0.5, "degrade: a mover scoring this or more is "
       "never given up", acts_in=RULE_MODES, rule=Rule.DEGRADE, search=(0.2, 0.9)),
    _m("cut_behind_m", float, 0.0, 100.0, 0.0, 0.5, "metres behind its object's near depth "
       "from which mask pixels are cut (0: off)", acts_in=MASK_MODES, needs=("depth",), off=0.0,
       search=(0.0, 1.5)),
    _m("motion_odds", float, 1.0, 1e6, 1.0, 10.0, "seg/fusion: odds by which the epipolar "
       "check's moving/static decision weighs on an uncertain mobility (1: no check)",
       acts_in=WEIGHED_MODES, needs=("history",), off=1.0, search=(1.0, 100.0), log=True),
    _m("motion_layer_px", int, 0, 1_000_000, 0, 100, "keep what moved in behind an object's "
       "near layer when it covers this many px (0: off)", acts_in=MASK_MODES,
       needs=("depth", "camera", "history"), off=0, search=(0, 600)),
    _m("still_frames", int, 0, 1000, 0, 20, "an object whose depth has not changed against "
       "the frames this many and half as many back is static (0: off)",
       needs=("depth", "camera", "history"), off=0, search=(0, 40)),
    # -- the track stage (TrackSettings): the knobs sweeps turn; the rest are constants of
    # slimseg.dynamic.track_settings
    _t("high", float, 0.0, 1.0, 0.25, "first-pass (BYTE) score threshold"),
    _t("low", float, 0.0, 1.0, 0.05, "second-pass score threshold, for confirmed tracks"),
    _t("new", float, 0.0, 1.0, 0.25, "score that opens a strong track (one that can coast); "
       "0.1 wins back walkers the model scores low with --rate N (docs/tracking.md §5.3)"),
    _t("max_coast", int, 0, 1000, 3, "frames a lost track's mask is emitted (0: never)"),
    _t("coast_decay", float, 0.0, 1.0, 0.7, "mobility factor per missed frame"),
    _t("coast_dilate_px", int, 0, 100, 2, "px of dilation per missed frame"),
    _t("depth_band_m", float, 0.0, 100.0, 0.4, "depth band of a coasted mask in metres "
       "(0: off)"),
    _t("p_alpha", float, 0.0, 1.0, 0.3, "moving-probability update weight of the epipolar "
       "modes", acts_in=tuple(EPIPOLAR_MODES)),
    _t("own_matches", int, 0, 10_000, 6, "ORB matches on a mask that move it (and a late "
       "model result) by the object's own motion (0: the camera motion and the track's "
       "velocity only)"),
)  # fmt: skip
BY_KEY: dict[str, Knob] = {k.key: k for k in KNOBS}
MASKING_KEYS: tuple[str, ...] = tuple(k.key for k in KNOBS if k.group == "masking")
TRACK_KEYS: tuple[str, ...] = tuple(k.key for k in KNOBS if k.group == "track")
MASKING_PRESETS: tuple[str, ...] = ("papers", "slimseg")


def knob(key: str) -> Knob:
    """The knob called ``key``; :class:`KnobError` listing the keys otherwise."""
    if key not in BY_KEY:
        raise KnobError(f"unknown setting {key!r}; valid: {', '.join(BY_KEY)}")
    return BY_KEY[key]


def preset_values(name: str) -> dict[str, Value]:
    """``{key: value}`` of the preset ``name`` (``papers``, ``slimseg`` or the track stage's
    ``coast``)."""
    return {k.key: k.presets[name] for k in KNOBS if name in k.presets}


def papers(key: str) -> Value:
    """The papers preset's value of ``key``: the equations' own numbers, which the levers
    implementing them use as their defaults."""
    return BY_KEY[key].presets["papers"]


def shipped(key: str) -> Value:
    """The shipped (``slimseg``) preset's value of ``key`` (a lever's default when on)."""
    return BY_KEY[key].presets["slimseg"]


def unmet(values: Mapping[str, Value], have: Iterable[str]) -> dict[str, tuple[str, ...]]:
    """``{key: what it lacks}`` for the knobs that ``values`` switches on (not at their
    ``off``) and whose needs (``depth``, ``camera``, ...) are not all in ``have``: levers
    that would do nothing."""
    got = set(have)
    out = {}
    for key, value in values.items():
        k = BY_KEY[key]
        missing = tuple(n for n in k.needs if n not in got)
        if k.off is not None and value != k.off and missing:
            out[key] = missing
    return out
