"""``slimseg <command>``: the single command-line entry point."""

from __future__ import annotations

import argparse
import logging
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


class _StdoutHandler(logging.StreamHandler):
    """Writes each record to the *current* ``sys.stdout`` (which tests may replace)."""

    def emit(self, record: logging.LogRecord) -> None:
        self.setStream(sys.stdout)
        super().emit(record)


_CLI_HANDLER = _StdoutHandler()
_CLI_HANDLER.setFormatter(logging.Formatter("%(message)s"))


def configure_logging() -> None:
    """The library's INFO lines (``slimseg.*`` loggers) printed as plain lines on stdout;
    idempotent (one handler however often ``main`` runs in a process)."""
    root = logging.getLogger("slimseg")
    if _CLI_HANDLER not in root.handlers:
        root.addHandler(_CLI_HANDLER)
    if root.level == logging.NOTSET:
        root.setLevel(logging.INFO)


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
    configure_logging()
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
