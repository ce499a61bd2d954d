"""The one boundary between a reader of user files and the decoders it calls.

A recording, a model's metadata or any file a user hands over is parsed by libraries
(protobuf, ``json``, ``struct``, numpy, OpenCV, mcap, rosbags) that raise whatever they raise:
``DecodeError``, ``KeyError``, ``TypeError``, ``struct.error``, ``cv2.error``,
``RecursionError`` on deep nesting, ``MemoryError`` or ``OverflowError`` on a size no file
should claim. :func:`decoding` turns every one of them into one :class:`SlimsegError` line
naming what was being read (the file, and where it has them the topic and message index), so
the CLI prints one line and exits 2; an error that is already a ``SlimsegError`` passes as it
is.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from slimseg.errors import SlimsegError
from slimseg.utils.text import printable

MAX_REASON = 300  # characters of a decoder's own message kept in the line


def reason(e: BaseException) -> str:
    """One line, escaped for the terminal: the exception's message, or its type without one
    (``RecursionError`` and ``MemoryError`` say what they are)."""
    text = " ".join(" ".join(str(a) for a in e.args).split())
    if isinstance(e, (RecursionError, MemoryError, OverflowError)) or not text:
        text = f"{type(e).__name__}: {text}" if text else type(e).__name__
    return printable(text[:MAX_REASON])


@contextmanager
def decoding(what: str) -> Iterator[None]:
    """Run a decoder: any exception but a ``SlimsegError`` (and ``KeyboardInterrupt``,
    ``SystemExit``) leaves as ``SlimsegError("<what>: <reason>")``; ``what`` names the input
    (``"bag x.mcap: message 3 on /camera/rgb"``) and is escaped for the terminal."""
    try:
        yield
    except SlimsegError:
        raise
    except Exception as e:  # the boundary: every decoder's every error, by design
        raise SlimsegError(f"{printable(what)}: {reason(e)}") from None
