"""Text from data files made safe to print: terminal control sequences shown, not obeyed.

A ``file_name`` in ``annotations.json``, a class name or a path may hold ``ESC [2J`` (clear the
screen), a carriage return or a bidirectional override; printed raw, it could erase or fake
a report line. :func:`printable` writes every non-printable character as its Python escape
(``\\x1b``, ``\\r``, ``\\u202e``), the way ``repr`` would, and leaves all other text, non-ASCII
letters included, as it is.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TextIO


def printable(text: object, newlines: bool = False) -> str:
    """``str(text)`` with every non-printable character escaped (``\\x1b[2J`` stays 7 visible
    characters); ``newlines``: keep ``\\n`` (multi-line log messages, tables)."""
    s = str(text)
    if s.isprintable():
        return s
    return "".join(c if c.isprintable() or (newlines and c == "\n") else _escape(c) for c in s)


def _escape(c: str) -> str:
    code = ord(c)
    named = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}
    if c in named:
        return named[c]
    return (
        f"\\x{code:02x}"
        if code < 0x100
        else f"\\u{code:04x}"
        if code < 0x10000
        else f"\\U{code:08x}"
    )


# what progress bars (tqdm, Lightning's on stdout) write to redraw themselves: a carriage
# return and "cursor up"; every other control character is escaped on the CLI's stdout
_PROGRESS = re.compile(r"(\r|\x1b\[A)")


def _shown(text: str) -> str:
    return "".join(c if c.isprintable() or c in "\n\t" else _escape(c) for c in text)


class PrintableStream:
    """A text stream writing to ``stream`` with every non-printable character escaped
    (:func:`printable`) but newlines, tabs and a progress bar's redraws: the CLI's stdout
    while a command runs, so an output path, a class name or any text from a file never moves
    the cursor, recolours or clears the screen, whichever print shows it."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream

    def write(self, text: str) -> int:
        n = len(text)
        if not text.isprintable():
            parts = _PROGRESS.split(text)
            text = "".join(p if _PROGRESS.fullmatch(p) else _shown(p) for p in parts)
        self.stream.write(text)
        return n

    def flush(self) -> None:
        self.stream.flush()

    def fileno(self) -> int:
        return self.stream.fileno()

    def isatty(self) -> bool:
        return self.stream.isatty()

    @property
    def encoding(self) -> str:
        return self.stream.encoding


@contextmanager
def printable_stdout() -> Iterator[None]:
    """``sys.stdout`` a :class:`PrintableStream` over itself while the block runs."""
    before = sys.stdout
    sys.stdout = PrintableStream(before)
    try:
        yield
    finally:
        sys.stdout = before
