"""``--gt-dropout RATE:BURST[:SEED]``: ground-truth instances with simulated missed detections
(the track stage's test bench), shared by ``slimseg dynamic`` and ``slimseg slam-eval``."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import TypeVar

from slimseg.dynamic.annotations import Dropout
from slimseg.errors import SlimsegError

T = TypeVar("T")


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


def dropout_from_args(args: argparse.Namespace) -> Dropout | None:
    """``--gt-dropout``, refused without ``--gt-instances``."""
    if args.gt_dropout is not None and not args.gt_instances:
        raise SlimsegError("--gt-dropout acts on ground-truth instances: add --gt-instances")
    return args.gt_dropout
