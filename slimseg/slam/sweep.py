"""``slam-eval --sweep KEY=v1,v2,...``: parse the sweep and list the settings it evaluates.

Keys: every knob of :data:`slimseg.dynamic.knobs.KNOBS`, under the name ``--set`` and the
settings use (:data:`SWEEP_KEYS`: the masking settings; :data:`TRACK_SWEEP_KEYS`: the track
stage's, with ``--track``). A key that changes nothing in the chosen mode (the registry's
``acts_in``) is refused.

Modes: ``oneway`` varies one key at a time, the others at the base settings (the chosen
preset with any ``--set`` applied); ``grid`` evaluates the full product. Both always include
the base settings, and every named preset not already among the points is added as a
reference.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace

from slimseg.dynamic.knobs import BY_KEY, MASKING_KEYS, TRACK_KEYS, KnobError
from slimseg.dynamic.masking_settings import PRESETS, MaskingSettings, SettingsError, preset_name
from slimseg.dynamic.track_settings import TrackSettings, TrackSettingsError

# the keys: every knob of the registry (masking, and the track stage's with --track), one name
# per knob (the settings field, the --set key, the metadata key)
SWEEP_KEYS: tuple[str, ...] = MASKING_KEYS
TRACK_SWEEP_KEYS: tuple[str, ...] = TRACK_KEYS
SWEEP_MODES = ("oneway", "grid")


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
        out[key] = tuple(dict.fromkeys(parsed))
    if not out:
        raise SweepError("--sweep: nothing to sweep")
    return out


def _number(key: str, text: str, item: str) -> Value:
    """``text`` parsed and checked by the knob ``key``."""
    try:
        return BY_KEY[key].parse(text)
    except KnobError as e:
        raise SweepError(f"--sweep {item!r}: {e}") from None


def check_mode(spec: dict[str, tuple[Value, ...]], mode: str, gt_instances: bool) -> None:
    """Refuse keys that cannot change ``mode``'s masks (or ``conf`` on score-1 instances)."""
    for key in spec:
        modes = BY_KEY[key].acts_in
        if mode not in modes:
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
        return None if track is None else getattr(track, key)
    return settings.as_dict()[key]


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
        masking = {k: v for k, v in combo.items() if k in SWEEP_KEYS}
        knobs = {k: v for k, v in combo.items() if k in TRACK_SWEEP_KEYS}
        s = base.with_values(**masking)
        try:
            t = track.with_values(**knobs) if track is not None else None
        except TrackSettingsError as e:  # e.g. low above high
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
