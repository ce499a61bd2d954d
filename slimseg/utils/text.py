"""Text from data files made safe to print: terminal control sequences shown, not obeyed.

A ``file_name`` in ``annotations.json``, a class name or a path may hold ``ESC [2J`` (clear the
screen), a carriage return or a bidirectional override; printed raw, it could erase or fake
a report line. :func:`printable` writes every non-printable character as its Python escape
(``\\x1b``, ``\\r``, ``\\u202e``), the way ``repr`` would, and leaves all other text, non-ASCII
letters included, as it is.
"""

from __future__ import annotations


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
