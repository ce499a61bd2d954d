"""The chain's options, generated from the knob registry (:mod:`slimseg.dynamic.knobs`):
``--preset papers|slimseg``, ``--set KEY=VALUE ...`` for any knob (masking or track stage: the
same keys as ``slam-eval --sweep``, the settings fields and the metadata), ``--track
[PRESET]`` and ``--rate N|budget:MS|thread`` (the model's rate, as the API's ``rate=``)."""

from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path

from slimseg.dynamic.chain_config import TrackPlan
from slimseg.dynamic.knobs import BY_KEY, KNOBS, Knob, KnobError, Value, knob
from slimseg.dynamic.masking_settings import (
    CALIBRATED,
    DEFAULT_PRESET,
    PRESETS,
    MaskingSettings,
    preset,
)
from slimseg.dynamic.model_rate import EVERY_FRAME, ModelRate
from slimseg.dynamic.track_settings import (
    DEFAULT_TRACK_PRESET,
    TRACK_PRESETS,
    TrackSettings,
    track_preset,
)
from slimseg.errors import SlimsegError


def _pair(text: str) -> tuple[str, str]:
    """``KEY=VALUE`` → ``(key, text)``; :func:`settings_from_args` checks both (its one-line
    error names the knob and its range)."""
    key, sep, value = (part.strip() for part in text.partition("="))
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"{text!r}: expected KEY=VALUE (e.g. conf=0.2)")
    return key, value


def knob_table(knobs: tuple[Knob, ...] = KNOBS) -> str:
    """One line per knob for ``--help``: key, default of each preset, what it does."""
    lines = []
    for k in knobs:
        values = "/".join(f"{v:g}" if not isinstance(v, str) else v for v in k.presets.values())
        notes = [f"{k.rule} rule only"] if k.rule else []
        notes += [f"needs {', '.join(n for n in k.needs if n != 'track')}"] * bool(
            set(k.needs) - {"track"}
        )
        text = f"{k.key} ({values}): {k.help}" + "".join(f"; {n}" for n in notes)
        lines += textwrap.wrap(text, 78, initial_indent="  ", subsequent_indent="      ")
    return "\n".join(lines)


def add_settings_args(
    p: argparse.ArgumentParser, *, masking: bool = True, rate: bool = True
) -> None:
    """``--preset`` and ``--set`` (``masking``), ``--track`` and (``rate``) ``--rate``."""
    g = p.add_argument_group("masking chain (docs/settings.md; every key in the epilog)")
    p.set_defaults(preset=None, settings=[], rate=None)
    if masking:
        g.add_argument("--preset", choices=(*PRESETS, CALIBRATED), default=None,
                       help=f"named masking settings (default: the model's own {CALIBRATED} "
                       f"preset when its export has one, else {DEFAULT_PRESET}; slimseg "
                       "calibrate makes one)")  # fmt: skip
        g.add_argument(
            "--set",
            dest="settings",
            metavar="KEY=VALUE",
            type=_pair,
            nargs="+",
            action="extend",
            default=[],
            help="override a knob of the preset (e.g. conf=0.2 motion_odds=1); a track-stage "
            "key implies --track",
        )
        shown = ", ".join(PRESETS)
        p.epilog = (f"settings (--set KEY=VALUE; values {shown} / track coast):\n"
                    f"{knob_table()}")  # fmt: skip
        p.formatter_class = argparse.RawDescriptionHelpFormatter
    g.add_argument(
        "--track",
        nargs="?",
        const=DEFAULT_TRACK_PRESET,
        default=None,
        choices=tuple(TRACK_PRESETS),
        metavar="PRESET",
        help="carry masks across frames (docs/tracking.md): BYTE association, camera-motion-"
        "compensated prediction, coasting over missed detections, a moving probability "
        f"(presets {', '.join(TRACK_PRESETS)}; bare --track: {DEFAULT_TRACK_PRESET})",
    )
    if rate:
        g.add_argument(
            "--rate",
            default=None,
            metavar="N|budget:MS|thread",
            help="the model's rate (needs --track): every N-th frame, a mean budget of MS per "
            "frame, or its own thread (frames replayed in real time, masked with the newest "
            "result); default every frame",
        )


def base_masking(preset_name: str | None, model: str | None, notes: list[str]) -> MaskingSettings:
    """The settings ``--set`` applies to: the named preset; with none named, the model's own
    ``calibrated`` preset when ``model`` is an export that carries one, else the shipped
    defaults (for an export without one, a note is added to ``notes``: the command prints it
    once its inputs have loaded, so a bad input still ends in one line)."""
    if preset_name is not None and preset_name != CALIBRATED:
        return preset(preset_name)
    if model is None or Path(model).suffix != ".onnx":
        if preset_name == CALIBRATED:
            raise SlimsegError(f"--preset {CALIBRATED} is a model's own: give --model X.onnx "
                               "(an export slimseg calibrate wrote)")  # fmt: skip
        return preset(DEFAULT_PRESET)
    from slimseg.deploy.calibrated import model_masking, read_model_metadata

    settings, note = model_masking(read_model_metadata(model), model)
    if note is not None:
        if preset_name == CALIBRATED:
            raise SlimsegError(f"--preset {CALIBRATED}: {note}")
        notes.append(f"note: {note}")
    return settings


def settings_from_args(
    args: argparse.Namespace, model: str | None = None, notes: list[str] | None = None
) -> tuple[MaskingSettings, TrackPlan]:
    """The preset (:func:`base_masking`: ``model``'s own by default) with every ``--set``
    applied, and the track stage with its rate (validated: a :class:`SlimsegError` names a bad
    value). ``notes``: where the lines to print once the inputs have loaded go (None: printed
    on stderr now)."""
    said: list[str] = [] if notes is None else notes
    given: dict[str, Value] = {}
    for key, text in args.settings:
        try:
            value = knob(key).parse(text)
        except KnobError as e:
            raise KnobError(f"--set {e}") from None
        if key in given and given[key] != value:
            raise SlimsegError(f"--set {key} given twice ({given[key]} and {value})")
        given[key] = value
    track_given = {k: v for k, v in given.items() if BY_KEY[k].group == "track"}
    masking_given = {k: v for k, v in given.items() if k not in track_given}
    masking = base_masking(args.preset, model, said).with_values(**masking_given)
    if notes is None:
        for line in said:
            print(line, file=sys.stderr)
    for key in masking_given:
        if masking.inert(key):
            print(f"note: --set {key} changes nothing under rule {masking.rule} "
                  f"(it acts under {BY_KEY[key].rule})", file=sys.stderr)  # fmt: skip
    track: TrackSettings | None = None
    if args.track is not None or track_given:
        track = track_preset(args.track or DEFAULT_TRACK_PRESET).with_values(**track_given)
    rate = EVERY_FRAME if args.rate is None else ModelRate.parse(args.rate)
    return masking, TrackPlan(track, rate)
