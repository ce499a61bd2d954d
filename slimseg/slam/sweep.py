"""``slam-eval --sweep KEY=v1,v2,...``: parse the sweep and list the settings it evaluates.

Keys (:data:`SWEEP_KEYS`) name fields of :class:`slimseg.dynamic.masking_settings.MaskingSettings`:
``conf`` (detector score threshold), ``dilation`` (px), ``min_static`` (Eq. 1),
``m_th_start`` / ``m_th_step`` (Eq. 1), ``ratio`` (Eq. 3's fraction), ``t_o`` (Eq. 4). With
``--track``, the keys of :data:`TRACK_SWEEP_KEYS` name knobs of the track stage
(:class:`slimseg.dynamic.track_settings.TrackSettings`): ``max_coast``, ``coast_decay``,
``coast_dilate``, ``track_high``, ``track_low``, ``depth_band``, ``p_alpha``.

Modes: ``oneway`` varies one key at a time, the others at the base settings (the chosen
preset with any flags applied); ``grid`` evaluates the full product. Both always include the
base settings, and every named preset not already among the points is added as a reference.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace

from slimseg.dynamic.masking_settings import PRESETS, MaskingSettings, SettingsError, preset_name
from slimseg.dynamic.modes import EPIPOLAR_MODES, WEIGHED_MODES, Mode
from slimseg.dynamic.track_settings import TrackSettings, TrackSettingsError, check_track_value

SWEEP_KEYS: dict[str, str] = {
    "conf": "conf",
    "dilation": "dilation_px",
    "min_static": "min_static",
    "m_th_start": "m_th_start",
    "m_th_step": "m_th_step",
    "ratio": "frame_ratio",
    "t_o": "t_o",
    "rule": "rule",
    "keep_score": "keep_score",
    "cut_behind": "cut_behind_m",
    "motion_odds": "motion_odds",
    "motion_layer": "motion_layer_px",
    "still": "still_frames",
}
# sweep key -> TrackSettings field (the track stage's knobs; they need --track)
TRACK_SWEEP_KEYS: dict[str, str] = {
    "max_coast": "max_coast",
    "coast_decay": "coast_decay",
    "coast_dilate": "coast_dilate_px",
    "track_high": "high",
    "track_low": "low",
    "depth_band": "depth_band_m",
    "p_alpha": "p_alpha",
}
INT_KEYS = ("dilation", "min_static", "max_coast", "coast_dilate", "motion_layer", "still")
WORD_KEYS = ("rule",)  # values are names, not numbers
SWEEP_MODES = ("oneway", "grid")
FUSION_MODES = (Mode.FUSION, Mode.FUSION_EPIPOLAR)
RULE_MODES = tuple(m for m in Mode if m != Mode.BOX_DEPTH_RANSAC)  # Eq. 1 or the degrading rule
# keys that change nothing in some masking modes (a sweep of them there would be flat noise)
ACTS_IN: dict[str, tuple[Mode, ...]] = {
    "ratio": FUSION_MODES,
    "t_o": FUSION_MODES,
    "min_static": RULE_MODES,
    "m_th_step": RULE_MODES,
    "rule": RULE_MODES,
    "keep_score": RULE_MODES,
    "cut_behind": tuple(m for m in RULE_MODES if m != Mode.BOX),  # masks to cut
    "motion_odds": WEIGHED_MODES,
    "motion_layer": tuple(m for m in RULE_MODES if m != Mode.BOX),  # the cut's masks
    "p_alpha": tuple(EPIPOLAR_MODES),
}


class SweepError(SettingsError):
    """A malformed ``--sweep`` (one line naming the item and what to do)."""


Value = float | int | str


def parse_sweep(items: list[str]) -> dict[str, tuple[Value, ...]]:
    """``["conf=0.1,0.25", "dilation=0,5"]`` → ``{"conf": (0.1, 0.25), "dilation": (0, 5)}``
    (key order kept, duplicate values dropped); every value checked against its range."""
    out: dict[str, tuple[Value, ...]] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise SweepError(f"--sweep {item!r}: expected KEY=v1,v2,... (e.g. conf=0.1,0.25)")
        if key not in SWEEP_KEYS and key not in TRACK_SWEEP_KEYS:
            valid = ", ".join([*SWEEP_KEYS, *TRACK_SWEEP_KEYS])
            raise SweepError(f"--sweep {item!r}: unknown key {key!r}; valid: {valid}")
        if key in out:
            raise SweepError(f"--sweep {key} given twice: list all its values in one item")
        values = [v.strip() for v in text.split(",") if v.strip()]
        if not values:
            raise SweepError(f"--sweep {item!r}: no values after '='")
        parsed = [_number(key, v, item) for v in values]
        for v in parsed:
            _check(key, v, item)
        out[key] = tuple(dict.fromkeys(parsed))
    if not out:
        raise SweepError("--sweep: nothing to sweep")
    return out


def _number(key: str, text: str, item: str) -> Value:
    if key in WORD_KEYS:
        return text
    try:
        return int(text) if key in INT_KEYS else float(text)
    except ValueError:
        kind = "a whole number" if key in INT_KEYS else "a number"
        raise SweepError(f"--sweep {item!r}: {text!r} is not {kind}") from None


def _check(key: str, value: Value, item: str) -> None:
    from slimseg.dynamic.masking_settings import check_value

    try:
        if key in TRACK_SWEEP_KEYS:
            check_track_value(TRACK_SWEEP_KEYS[key], value)
        else:
            check_value(SWEEP_KEYS[key], value)
    except (SettingsError, TrackSettingsError) as e:
        raise SweepError(f"--sweep {item!r}: {e}") from None


def check_mode(spec: dict[str, tuple[Value, ...]], mode: str, gt_instances: bool) -> None:
    """Refuse keys that cannot change ``mode``'s masks (or ``conf`` on score-1 instances)."""
    for key in spec:
        modes = ACTS_IN.get(key)
        if modes is not None and mode not in modes:
            raise SweepError(f"--sweep {key}: has no effect in mode {mode} (acts in "
                             f"{', '.join(modes)}); choose --modes {modes[0]}")  # fmt: skip
    if gt_instances and "conf" in spec:
        raise SweepError("--sweep conf: ground-truth instances (--gt-instances) all score 1")


@dataclass(frozen=True)
class SweepPoint:
    """One evaluated setting: ``label`` (``base``, ``conf=0.1``, ``preset papers``, ...),
    the full ``settings`` and the swept ``values`` by sweep key."""

    label: str
    settings: MaskingSettings
    values: dict[str, Value] = field(default_factory=dict)
    reference: bool = False
    """a named preset added for comparison, not one of the sweep's points"""
    track: TrackSettings | None = None
    """the track stage's knobs at this point (None: the stage is off)"""


def key_value(settings: MaskingSettings, track: TrackSettings | None, key: str) -> Value | None:
    """The value of sweep ``key`` in the masking ``settings`` or the ``track`` knobs."""
    if key in TRACK_SWEEP_KEYS:
        return None if track is None else getattr(track, TRACK_SWEEP_KEYS[key])
    return getattr(settings, SWEEP_KEYS[key])


def values_of(
    settings: MaskingSettings,
    keys: list[str] | tuple[str, ...],
    track: TrackSettings | None = None,
) -> dict[str, Value]:
    """The sweep-key values of ``settings`` (and ``track``)."""
    return {k: key_value(settings, track, k) for k in keys}


def sweep_points(
    base: MaskingSettings,
    spec: dict[str, tuple[Value, ...]],
    how: str = "oneway",
    ignore_conf: bool = False,
    track: TrackSettings | None = None,
) -> list[SweepPoint]:
    """The settings to evaluate: the base first, then the sweep's points (``oneway`` or
    ``grid``), then each named preset not among them (``reference``). No setting twice; with
    ``ignore_conf`` (ground-truth instances, all scoring 1) settings differing only in
    ``conf`` count as the same, and a preset equal to a point is named in its label.
    ``track``: the track stage's base knobs (None: off; track keys then refused)."""
    if how not in SWEEP_MODES:
        raise SweepError(f"--sweep-mode {how!r}: valid: {', '.join(SWEEP_MODES)}")
    keys = list(spec)
    track_keys = [k for k in keys if k in TRACK_SWEEP_KEYS]
    if track_keys and track is None:
        raise SweepError(f"--sweep {track_keys[0]}: a knob of the track stage; add --track")

    def effective(s: MaskingSettings) -> MaskingSettings:
        return s.with_values(conf=base.conf) if ignore_conf else s

    def same(p: SweepPoint, s: MaskingSettings, t: TrackSettings | None) -> bool:
        return effective(p.settings) == effective(s) and p.track == t

    name = preset_name(base)
    points = [SweepPoint(f"base ({name})" if name else "base", base,
                         values_of(base, keys, track), track=track)]  # fmt: skip
    if how == "oneway":
        combos = [{k: v} for k in keys for v in spec[k]]
    else:
        combos = [dict(zip(keys, c, strict=True)) for c in itertools.product(*spec.values())]
    for combo in combos:
        masking = {SWEEP_KEYS[k]: v for k, v in combo.items() if k in SWEEP_KEYS}
        knobs = {TRACK_SWEEP_KEYS[k]: v for k, v in combo.items() if k in TRACK_SWEEP_KEYS}
        s = base.with_values(**masking)
        try:
            t = track.with_values(**knobs) if track is not None else None
        except TrackSettingsError as e:  # e.g. track_low above track_high
            raise SweepError(f"--sweep {combo}: {e}") from None
        if any(same(p, s, t) for p in points):
            continue
        changed = {k: v for k, v in combo.items() if key_value(base, track, k) != v}
        label = " ".join(f"{k}={format_value(v)}" for k, v in changed.items())
        points.append(SweepPoint(label, s, values_of(s, keys, t), track=t))
    for pname, s in PRESETS.items():
        equal = [i for i, p in enumerate(points) if same(p, s, track)]
        if not equal:
            points.append(SweepPoint(f"preset {pname}", s, values_of(s, keys, track),
                                     reference=True, track=track))  # fmt: skip
        elif points[equal[0]].settings != s:  # equal masks, another conf: say so in the label
            p = points[equal[0]]
            points[equal[0]] = replace(p, label=f"{p.label} (= preset {pname})")
    return points


def format_value(v: Value) -> str:
    """A sweep value as the tables and labels print it (``0.1``, ``5``, ``degrade``)."""
    return f"{v:g}" if isinstance(v, float) else str(v)


def slice_through(points: list[SweepPoint], key: str, center: SweepPoint) -> list[SweepPoint]:
    """The points that differ from ``center`` in ``key`` only (``center`` included), sorted by
    that key's value: one curve of the sweep plot."""
    others = [k for k in (*SWEEP_KEYS, *TRACK_SWEEP_KEYS) if k != key]

    def value(p: SweepPoint, k: str) -> Value | None:
        return key_value(p.settings, p.track, k)

    same = [
        p
        for p in points
        if not p.reference and all(value(p, k) == value(center, k) for k in others)
    ]
    return sorted(same, key=lambda p: value(p, key))
