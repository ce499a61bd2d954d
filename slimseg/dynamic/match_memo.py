"""Remembered feature matches, for replaying the same frames under many settings.

Matching two frames' ORB descriptors (:func:`slimseg.dynamic.epipolar.match_features`) depends
on the descriptors alone, never on a masking setting, yet a chain replaying a sequence matches
the same pairs for every candidate a calibration scores: a fifth of a candidate's time
(docs/calibrate.md). Inside :func:`remembered_matches` the matches are kept by the content of
both descriptor sets (a 16-byte BLAKE2 digest of each, with its shape), so a pair seen before
is answered from memory with exactly the rows it gave the first time. Outside it nothing is
kept: a SLAM loop never sees the same pair twice.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar

import numpy as np

#: Pairs kept at most (least recently used first out), about 100 MB of rows (~300 matches of
#: 16 bytes each); a 60-frame sequence met ~300 new pairs under its first candidate, and most
#: of them again under every later one.
CAPACITY = 20_000


class MatchMemo:
    """At most ``capacity`` match arrays keyed by the content of the arrays they came from;
    ``hits`` and ``misses`` count the lookups."""

    def __init__(self, capacity: int = CAPACITY) -> None:
        self.capacity = capacity
        self.hits = 0
        self.misses = 0
        self._rows: OrderedDict[tuple[object, ...], np.ndarray] = OrderedDict()

    def lookup(
        self,
        arrays: tuple[np.ndarray, ...],
        extra: tuple[object, ...],
        compute: Callable[[], np.ndarray],
    ) -> np.ndarray:
        """The rows ``compute()`` gave for these ``arrays`` (and ``extra`` arguments) before,
        else ``compute()``'s now, remembered. The array returned is read-only (it is shared)."""
        key = tuple(_digest(a) for a in arrays) + extra
        rows = self._rows.get(key)
        if rows is not None:
            self.hits += 1
            self._rows.move_to_end(key)
            return rows
        self.misses += 1
        rows = compute()
        rows.flags.writeable = False
        self._rows[key] = rows
        if len(self._rows) > self.capacity:
            self._rows.popitem(last=False)
        return rows


def _digest(a: np.ndarray) -> tuple[bytes, tuple[int, ...], str]:
    data = np.ascontiguousarray(a)
    return hashlib.blake2b(data.tobytes(), digest_size=16).digest(), data.shape, data.dtype.str


_ACTIVE: ContextVar[MatchMemo | None] = ContextVar("slimseg_match_memo", default=None)


def active() -> MatchMemo | None:
    """The memo of the enclosing :func:`remembered_matches`, or None."""
    return _ACTIVE.get()


@contextmanager
def remembered_matches(memo: MatchMemo | None = None) -> Iterator[MatchMemo]:
    """Feature matches computed inside this block are remembered in ``memo`` (a new one when
    None) and answered from it; pass the same memo to several blocks to share what it holds."""
    token = _ACTIVE.set(memo if memo is not None else MatchMemo())
    try:
        yield _ACTIVE.get()  # type: ignore[misc]
    finally:
        _ACTIVE.reset(token)
