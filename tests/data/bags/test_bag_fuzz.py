"""The mutation fuzzer of ``tests/bag_fuzz.py``, bounded: 1,400 generated recordings (seeds 0 to
199 of each of the 7 profiles), and the cases it found in the readers before issue #62, pinned.
Each ends refused in one line or read exactly (frames in order where the format has no
checksum). The long run is ``python tests/bag_fuzz.py --cases 100000`` (docs/bags.md)."""

from __future__ import annotations

import logging
from pathlib import Path

import bag_fuzz as bf
import pytest

pytest.importorskip("rosbags")
pytest.importorskip("mcap_ros1")
pytest.importorskip("mcap_ros2")
pytest.importorskip("mcap_protobuf")
pytest.importorskip("foxglove")

CI_SEEDS = 200
# (profile, seed) the bounded run broke the property with before #62: wrong pixels or lost
# frames with no error (chunk CRCs unchecked), tracebacks (JSON and protobuf values trusted)
PINNED = [
    ("ros1.mcap", s) for s in (1, 8, 12, 13, 18, 30, 31, 34, 41, 45, 46, 49, 58, 59, 60, 78, 84,
                               91, 93, 103, 104, 121, 122, 133, 134, 135, 137, 145, 151, 153,
                               162, 169, 170, 171, 173, 193, 195)
] + [
    ("foxglove_sdk.mcap", s) for s in (15, 65, 68, 76, 80, 87, 91, 105, 118, 130, 156)
] + [
    ("foxglove_json.mcap", s) for s in (61, 77, 80, 86, 109, 126, 157, 197)
] + [
    ("foxglove_sdk.mcap", 1995),  # the long run's: a footer pointing past the file (OSError)
]  # fmt: skip


@pytest.fixture(scope="module")
def bases(tmp_path_factory: pytest.TempPathFactory) -> list[bf.Base]:
    root = tmp_path_factory.mktemp("fuzz")
    return bf.make_bases(root, bf.make_sequence(root / "seq"))


def test_every_profile_base_reads_as_its_folder(bases: list[bf.Base]) -> None:
    assert sorted(b.name for b in bases) == sorted(bf.PROFILES)
    first = bases[0].frames
    for b in bases:
        assert len(b.frames) == len(first) == 4, b.name
        assert bf._same(b.frames, first), b.name


def test_bounded_fuzz_run_finds_nothing(bases: list[bf.Base], tmp_path: Path, caplog) -> None:
    caplog.set_level(logging.CRITICAL)
    counts, findings = bf.fuzz(bases, CI_SEEDS * len(bases), tmp_path)
    assert findings == [], findings[:5]
    assert sum(counts.values()) == CI_SEEDS * len(bases)
    # the run exercises both outcomes, and every mutation kind reaches the reader
    assert counts["refused"] > 0 and counts["exact"] > 0, counts


@pytest.mark.parametrize(("name", "seed"), PINNED)
def test_pinned_cases_stay_fixed(bases: list[bf.Base], tmp_path: Path, name: str, seed: int):
    base = next(b for b in bases if b.name == name)
    outcome, what = bf.run_case(base, seed, tmp_path)
    assert outcome in ("refused", "exact"), (outcome, what)
