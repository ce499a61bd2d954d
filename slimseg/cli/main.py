"""``slimseg <command>``: the single command-line entry point.

Every user error ends in one line on stderr, ``slimseg <command>: error: <what and where>``,
and exit code 2: a :class:`~slimseg.errors.SlimsegError` from any reader or check, an
``OSError`` on a path (an output that cannot be written, an input that cannot be read) and a
bad option (argparse's own errors and those raised inside a ``type=`` parser). ``slimseg
--debug <command>`` or ``SLIMSEG_DEBUG=1`` lets the exception through with its traceback, for
bug reports. Any other exception is a bug and keeps its traceback.

Only the command that runs is imported (:mod:`slimseg.cli.commands`): ``slimseg --help`` and
the runtime's commands never load the training stack. A command whose module needs the
``train`` extra and lacks it ends in one line, ``slimseg train needs the training stack: pip
install 'slimseg[train]'``, and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import NoReturn

from slimseg.cli.commands import COMMANDS
from slimseg.errors import SlimsegError
from slimseg.utils.extras import is_train_module, train_hint
from slimseg.utils.outputs import ALLOW_OUTSIDE_ENV, ALLOW_OUTSIDE_FLAG
from slimseg.utils.text import printable, printable_stdout
from slimseg.version import __version__

DEBUG_ENV = "SLIMSEG_DEBUG"  # set to 1: user errors raise with their traceback (bug reports)


@contextmanager
def cli_logging() -> Iterator[None]:
    """While a command runs, the library's INFO lines (``slimseg.*`` loggers) print as plain
    lines on the current stdout (control characters escaped, see :func:`printable`); the
    logger is put back as it was afterwards (no handler outlives the command, so a library
    caller's logging is never changed for good). OpenCV's own warnings and errors (``[ WARN:0]
    ... PNG input buffer is incomplete``, ``[ERROR:0] ... IHDR chunk shall be first``) are off
    meanwhile: the readers report an unreadable file themselves, on one line."""
    import cv2  # here: `slimseg --help` never loads OpenCV

    logger = logging.getLogger("slimseg")
    handler = logging.StreamHandler(sys.stdout)
    handler.setFormatter(PrintableFormatter("%(message)s"))
    level, propagate = logger.level, logger.propagate
    logger.addHandler(handler)
    # a library that configured the root logger (onnxruntime's quantizer does) would print
    # every line a second time
    logger.propagate = False
    if level == logging.NOTSET:
        logger.setLevel(logging.INFO)
    cv2_level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(cv2_level)
        logger.removeHandler(handler)
        logger.setLevel(level)
        logger.propagate = propagate


class PrintableFormatter(logging.Formatter):
    """Log lines with terminal control characters escaped (:func:`printable`): library
    messages carry file names and class names read from data files."""

    def format(self, record: logging.LogRecord) -> str:
        return printable(super().format(record), newlines=True)


class OneLineParser(argparse.ArgumentParser):
    """argparse with its errors on one line (``slimseg <command>: error: ...``, exit 2)
    instead of the usage block; subcommand parsers are made of this class too."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {printable(message)} (see {self.prog} --help)\n")


def command_word(argv: Sequence[str]) -> str | None:
    """The command ``argv`` names: its first word that is not an option (the global options
    take no value), ``None`` when there is none."""
    return next((a for a in argv if not a.startswith("-")), None)


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The parser of ``slimseg``: every command listed, the one ``argv`` names (``None``:
    ``sys.argv``) complete with its options; the others' modules are not imported."""
    chosen = command_word(sys.argv[1:] if argv is None else argv)
    parser = OneLineParser(
        prog="slimseg",
        description="Build, train, ablate, fuse and export segmenters for dynamic SLAM.",
    )
    parser.add_argument("--version", action="version", version=f"slimseg {__version__}")
    parser.add_argument(
        "--debug",
        action="store_true",
        help=f"show the traceback of a user error (for bug reports; or set {DEBUG_ENV}=1)",
    )
    parser.add_argument(
        ALLOW_OUTSIDE_FLAG,
        action="store_true",
        help="read paths from data files (annotations.json file_name, rgb.txt/depth.txt, "
        "data.yaml splits) that are absolute or climb out of their root with '..' (refused "
        f"otherwise; or set {ALLOW_OUTSIDE_ENV}=1)",
    )
    sub = parser.add_subparsers(dest="command", metavar="<command>", required=True)
    for command in COMMANDS:
        if command.name == chosen:
            importlib.import_module(command.module).add_parser(sub)
        else:
            sub.add_parser(command.name, help=command.help)
    return parser


def describe_os_error(exc: OSError) -> str:
    """``OSError`` as a line naming the path(s): ``Not a directory: out/masks``."""
    what = exc.strerror or str(exc)
    paths = [str(p) for p in (exc.filename, exc.filename2) if p is not None]
    return f"{what}: {' -> '.join(paths)}" if paths else what


@contextmanager
def _outside_root(allowed: bool) -> Iterator[None]:
    """``--allow-outside-root``: :data:`ALLOW_OUTSIDE_ENV` set while the command runs (so
    data-loader workers and DDP ranks inherit it), put back after."""
    before = os.environ.get(ALLOW_OUTSIDE_ENV)
    if allowed:
        os.environ[ALLOW_OUTSIDE_ENV] = "1"
    try:
        yield
    finally:
        if allowed and before is None:
            del os.environ[ALLOW_OUTSIDE_ENV]
        elif allowed:
            os.environ[ALLOW_OUTSIDE_ENV] = before


def _debug(argv: Sequence[str] | None) -> bool:
    """``--debug`` given (looked up before parsing, which may itself fail) or the variable."""
    words = sys.argv[1:] if argv is None else argv
    return os.environ.get(DEBUG_ENV, "") not in ("", "0") or "--debug" in words


def main(argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` and run the command; user errors print one line and return 2."""
    debug = _debug(argv)
    try:
        parser = build_parser(argv)
    except ModuleNotFoundError as exc:  # the command's module needs an extra
        return _missing_extra(exc, command_word(sys.argv[1:] if argv is None else argv), debug)
    try:
        args = parser.parse_args(argv)
    except SlimsegError as exc:  # from a type= parser, which argparse lets through
        if debug:
            raise
        parser.error(str(exc))
    try:
        with printable_stdout(), cli_logging(), _outside_root(args.allow_outside_root):
            return int(args.run(args) or 0)
    except SlimsegError as exc:
        if debug:
            raise
        print(f"slimseg {args.command}: error: {printable(exc)}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:
        return _missing_extra(exc, args.command, debug)
    except KeyboardInterrupt:
        print(f"slimseg {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `slimseg ... | head`: the reader left; stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # so the interpreter's final flush cannot fail
        return 141
    except OSError as exc:  # a path the user gave: unreadable input, unwritable output
        if debug:
            raise
        line = printable(describe_os_error(exc))
        print(f"slimseg {args.command}: error: {line}", file=sys.stderr)
        return 2


def _missing_extra(exc: ModuleNotFoundError, command: str | None, debug: bool) -> int:
    """A module of the ``train`` extra missing: one line, exit 2 (any other: a bug, raised)."""
    if debug or not is_train_module(exc.name):
        raise exc
    print(train_hint(f"slimseg {command}"), file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
