"""``slimseg <command>``: the single command-line entry point."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from slimseg import __version__
from slimseg.cli import (
    ablate,
    bench,
    data,
    demo,
    dynamic,
    export,
    info,
    predict,
    slam,
    slam_eval,
    train,
    val,
)
from slimseg.errors import SlimsegError

# Each command module exposes ``add_parser(subparsers)`` and ``run(args) -> int``.
COMMANDS = (demo, info, data, train, val, ablate, export, predict, bench, dynamic, slam_eval, slam)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="slimseg",
        description="Build, train, ablate, fuse and export segmenters for dynamic SLAM.",
    )
    parser.add_argument("--version", action="version", version=f"slimseg {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="<command>", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` and run the command; user errors print one line and return 2."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except SlimsegError as exc:
        print(f"slimseg {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"slimseg {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
