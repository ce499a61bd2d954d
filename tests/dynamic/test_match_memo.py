"""Remembered matches: the same rows as matching afresh, answered from memory only inside the
block, and keyed by content (another subset of the same frame is another pair)."""

from __future__ import annotations

import numpy as np
import pytest

from slimseg.dynamic import match_memo
from slimseg.dynamic.epipolar import OrbFeatures, match_features, orb_features
from slimseg.dynamic.match_memo import MatchMemo, remembered_matches


def _frames() -> tuple[OrbFeatures, OrbFeatures]:
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 256, (240, 320), np.uint8)
    texture = np.repeat(np.repeat(texture[::4, ::4], 4, 0), 4, 1)
    shifted = np.roll(texture, 3, axis=1)
    return orb_features(np.dstack([texture] * 3)), orb_features(np.dstack([shifted] * 3))


def test_remembered_matches_equal_fresh_ones() -> None:
    a, b = _frames()
    fresh = match_features(a, b)
    assert len(fresh) > 50 and match_memo.active() is None
    memo = MatchMemo()
    with remembered_matches(memo):
        first = match_features(a, b)
        again = match_features(OrbFeatures(a.keypoints, a.descriptors.copy()), b)  # by content
        half = match_features(OrbFeatures(a.keypoints[::2], a.descriptors[::2]), b)
    assert np.array_equal(first, fresh) and np.array_equal(again, fresh)
    assert (memo.hits, memo.misses) == (1, 2)  # the subset is another pair
    halved = OrbFeatures(a.keypoints[::2], a.descriptors[::2])
    assert np.array_equal(half, match_features(halved, b))
    with pytest.raises(ValueError):
        again[0, 0] = 1  # shared rows are read-only
    assert match_memo.active() is None
    match_features(a, b)  # outside the block: nothing remembered
    assert memo.hits + memo.misses == 3


def test_capacity_drops_the_least_recently_used() -> None:
    memo = MatchMemo(capacity=2)
    arrays = [np.full((4, 32), k, np.uint8) for k in range(3)]
    calls = []

    def compute(k: int) -> np.ndarray:
        calls.append(k)
        return np.zeros((0, 2), np.int64)

    for k in (0, 1, 0, 2, 1):
        memo.lookup((arrays[k],), (), lambda k=k: compute(k))
    assert calls == [0, 1, 2, 1]  # 1 was the least recently used when 2 came in
