"""``slimseg <command>``: the single command-line entry point."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

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
from slimseg.version import __version__

# Each command module exposes ``add_parser(subparsers)`` and ``run(args) -> int``.
COMMANDS = (demo, info, data, train, val, ablate, export, predict, bench, dynamic, slam_eval, slam)


@contextmanager
def cli_logging() -> Iterator[None]:
    """While a command runs, the library's INFO lines (``slimseg.*`` loggers) print as plain
    lines on the current stdout; the logger is put back as it was afterwards (no handler
    outlives the command, so a library caller's logging is never changed for good)."""
    logger = logging.getLogger("slimseg")
    handler = logging.StreamHandler(sys.stdout)
    handler.setFormatter(logging.Formatter("%(message)s"))
    level, propagate = logger.level, logger.propagate
    logger.addHandler(handler)
    # a library that configured the root logger (onnxruntime's quantizer does) would print
    # every line a second time
    logger.propagate = False
    if level == logging.NOTSET:
        logger.setLevel(logging.INFO)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
        logger.propagate = propagate


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
        with cli_logging():
            return int(args.run(args) or 0)
    except SlimsegError as exc:
        print(f"slimseg {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"slimseg {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `slimseg ... | head`: the reader left; stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # so the interpreter's final flush cannot fail
        return 141


if __name__ == "__main__":
    sys.exit(main())
