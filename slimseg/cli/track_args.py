"""The track-stage options shared by ``slimseg dynamic``, ``slimseg slam-eval`` and
``slimseg predict``: ``--track [PRESET]``, one ``--track-*`` flag per knob of
:class:`slimseg.dynamic.track_settings.TrackSettings` (a flag overrides the preset, and implies
``--track``), ``--segment-every N`` and, for ground-truth instances, ``--gt-dropout``."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import TypeVar

from slimseg.cli.arg_types import count, number
from slimseg.dynamic.annotations import Dropout
from slimseg.dynamic.chain_config import TrackPlan
from slimseg.dynamic.model_rate import ModelRate
from slimseg.dynamic.track_settings import (
    DEFAULT_TRACK_PRESET,
    TRACK_PRESETS,
    TRACK_RANGES,
    TrackSettings,
    track_preset,
)
from slimseg.errors import SlimsegError

T = TypeVar("T")

# flag -> field: every knob, spelled --track-<field with dashes>
FLAGS: dict[str, str] = {f"--track-{name.replace('_', '-')}": name for name in TRACK_RANGES}


def add_track_args(p: argparse.ArgumentParser, segment_every: bool = True) -> None:
    """Add ``--track``, the knob flags and (``segment_every``) ``--segment-every``."""
    g = p.add_argument_group("track stage (docs/tracking.md): masks that remember")
    g.add_argument(
        "--track",
        nargs="?",
        const=DEFAULT_TRACK_PRESET,
        default=None,
        choices=tuple(TRACK_PRESETS),
        metavar="PRESET",
        help="carry masks across frames: BYTE association, camera-motion-compensated "
        "prediction, coasting over missed detections, a per-track moving probability "
        f"(presets {', '.join(TRACK_PRESETS)}; bare --track: {DEFAULT_TRACK_PRESET}); off by "
        "default: every frame judged alone",
    )
    base = TRACK_PRESETS[DEFAULT_TRACK_PRESET]
    for flag, field in FLAGS.items():
        _, _, integer, what = TRACK_RANGES[field]
        g.add_argument(flag, dest=f"track_{field}", type=int if integer else float,
                       default=None, metavar="N" if integer else "X",
                       help=f"{what} (default {getattr(base, field):g})")  # fmt: skip
    if segment_every:
        g.add_argument(
            "--segment-every",
            type=count(1),
            default=1,
            metavar="N",
            help="run the model on every N-th frame only; the tracks carry the masks between "
            "(needs --track; the total ms per frame is reported)",
        )


def add_rate_args(p: argparse.ArgumentParser) -> None:
    """``--budget-ms`` and ``--model-thread`` (with ``--fps``): the model's rate set by a time
    budget, or by the model itself on its own thread."""
    g = p.add_argument_group("model rate (with --track; docs/tracking.md section 6)")
    g.add_argument(
        "--budget-ms",
        type=number(0),
        default=0.0,
        metavar="MS",
        help="mean milliseconds per frame to stay within: the model runs on every N-th frame "
        "with N chosen from the measured model and masking times (instead of --segment-every)",
    )
    g.add_argument(
        "--model-thread",
        action="store_true",
        help="run the model on its own thread, as a runtime would: frames are replayed in real "
        "time and masked as they arrive with the newest finished model result, moved by each "
        "object's own ORB matches; the report gives the per-frame latency (the other modes are "
        "scored after the run, on what its rules saw)",
    )
    g.add_argument(
        "--fps",
        type=float,
        default=None,
        help="--model-thread: replay rate in frames per second (default: the sequence's "
        "timestamps; 0: as fast as the masking goes)",
    )


def add_dropout_arg(p: argparse.ArgumentParser) -> None:
    """``--gt-dropout RATE:BURST[:SEED]`` (with ``--gt-instances``)."""
    p.add_argument(
        "--gt-dropout",
        type=_option_type(Dropout.parse),
        default=None,
        metavar="RATE:BURST[:SEED]",
        help="with --gt-instances: drop each instance from RATE of its frames in bursts of "
        "BURST frames (simulated missed detections, e.g. 0.1:3)",
    )


def _option_type(parse: Callable[[str], T]) -> Callable[[str], T]:
    """``parse`` as an argparse ``type=``: its ``SlimsegError`` becomes argparse's own error,
    so the message names the option (``argument --gt-dropout: ...``) on one line."""

    def option_type(text: str) -> T:
        try:
            return parse(text)
        except SlimsegError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    return option_type


def track_settings_from_args(args: argparse.Namespace) -> TrackSettings | None:
    """The preset with every given knob applied; None when the stage is off."""
    given = {f: getattr(args, f"track_{f}") for f in FLAGS.values()
             if getattr(args, f"track_{f}") is not None}  # fmt: skip
    if args.track is None and not given:
        return None
    return track_preset(args.track or DEFAULT_TRACK_PRESET).with_values(**given)


def track_plan_from_args(args: argparse.Namespace) -> TrackPlan:
    """The validated stage and model rate (``SlimsegError`` names a bad option)."""
    every = getattr(args, "segment_every", 1)
    budget = getattr(args, "budget_ms", 0.0)
    thread = getattr(args, "model_thread", False)
    chosen = [f for f, on in (("--segment-every", every > 1), ("--budget-ms", budget > 0),
                              ("--model-thread", thread)) if on]  # fmt: skip
    if len(chosen) > 1:
        raise SlimsegError(f"{' and '.join(chosen)}: give one way to set the model's rate")
    rate = ModelRate(every=every, budget_ms=budget, thread=thread)
    return TrackPlan(track_settings_from_args(args), rate)  # a rate without --track: refused


def dropout_from_args(args: argparse.Namespace) -> Dropout | None:
    """``--gt-dropout``, refused without ``--gt-instances``."""
    if args.gt_dropout is not None and not args.gt_instances:
        raise SlimsegError("--gt-dropout acts on ground-truth instances: add --gt-instances")
    return args.gt_dropout
