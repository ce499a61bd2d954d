"""A mutation fuzzer over real recordings of every profile slimseg reads, shared by the bounded
run in the test suite (``tests/data/bags/test_bag_fuzz.py``) and the long one
(``python tests/bag_fuzz.py --cases 100000``, docs/bags.md).

The base recordings are written from one small TUM folder by the independent libraries
(``tests/profile_recordings.py``: mcap-ros1-support, mcap-ros2-support, foxglove-sdk,
mcap-protobuf-support, the mcap package's JSON writer) and by rosbags (a ROS 1 ``.bag``, a
rosbag2 SQLite folder). Each case takes one and applies a seeded mutation: bytes flipped, a run
of bytes garbled, the file cut, a byte range duplicated or deleted, a top-level MCAP record
duplicated, or the recording re-compressed (every message rewritten by the mcap package with
another compression and chunk size, optionally then flipped).

The property (:func:`run_case`): the reader refuses the recording with one ``SlimsegError``
line, or reads every frame exactly (the base's pixels, depth and stamps, in order). For
formats that carry checksums (MCAP) nothing else is allowed; a ROS 1 bag and a SQLite
database carry none, so a flipped pixel byte there cannot be seen by any reader: for those
the property is the boundary (one line, never another exception) and frames in order.
"""

from __future__ import annotations

import argparse
import random
import resource
import struct
import sys
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import profile_recordings as pr

from slimseg.data.bags.sequence import BagSequence
from slimseg.errors import SlimsegError

MCAP_MAGIC = b"\x89MCAP0\r\n"
# name → (writer, whether its format carries checksums over every byte read)
PROFILES = {
    "ros1.mcap": (pr.write_ros1_mcap, True),
    "ros2.mcap": (pr.write_ros2_mcap, True),
    "foxglove_sdk.mcap": (pr.write_foxglove_sdk, True),
    "foxglove_pb.mcap": (pr.write_foxglove_protobuf, True),
    "foxglove_json.mcap": (pr.write_foxglove_json, True),
    "ros1.bag": (None, False),
    "sqlite": (None, False),
}
MUTATIONS = ("flip", "garble", "cut", "duplicate", "delete", "record", "recompress")


@dataclass
class Base:
    """One base recording: its path, bytes (a file's, or a SQLite folder's database) and
    the frames it reads as."""

    name: str
    path: Path
    data: bytes
    frames: list[tuple[np.ndarray, np.ndarray, float]]
    checked: bool


def make_sequence(root: Path, frames: int = 4, size: tuple[int, int] = (64, 64)) -> Path:
    """A small synthetic TUM folder with whole-millimetre depth (what every writer keeps)."""
    from slimseg.data.synth import generate
    from slimseg.utils.atomic import write_png

    generate(root / "d", 0, 0, 64, 0, sequences=1, frames=frames, seq_size=size, progress=False)
    seq = root / "d" / "sequences" / "seq_000"
    for p in (seq / "depth").iterdir():
        raw = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        write_png(p, (np.round(raw / 5.0) * 5).astype(np.uint16))
    return seq


def read_all(path: Path) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Every frame of the recording at ``path``, in order."""
    with BagSequence(path) as seq:
        return [seq.load(i) for i in range(len(seq))]


def make_bases(root: Path, seq: Path) -> list[Base]:
    """The base recordings of :data:`PROFILES`, written from ``seq`` into ``root``."""
    from slimseg.data.bags.from_tum import tum_to_bag

    bases = []
    for name, (write, checked) in PROFILES.items():
        path = root / name
        if write is not None:
            write(seq, path)
        else:
            tum_to_bag(seq, path, storage="sqlite3" if name == "sqlite" else None)
        data = _payload(path).read_bytes()
        bases.append(Base(name, path, data, read_all(path), checked))
    return bases


def _payload(path: Path) -> Path:
    """The file whose bytes are mutated: the recording, or a rosbag2 folder's database."""
    return next(path.glob("*.db3")) if path.is_dir() else path


def _records(data: bytes) -> list[tuple[int, int]]:
    """``(offset, length)`` of each top-level MCAP record (stops at the first that overruns)."""
    out, pos = [], len(MCAP_MAGIC)
    while pos + 9 <= len(data):
        op, n = struct.unpack_from("<BQ", data, pos)
        if pos + 9 + n > len(data) or op == 0x02:
            break
        out.append((pos, 9 + n))
        pos += 9 + n
    return out


def _recompress(base: Base, rng: random.Random, out: Path) -> bytes:
    """``base`` rewritten message by message with the mcap package's writer: another
    compression and chunk size, the same schemas, channels, stamps and bytes."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    kind = rng.choice([CompressionType.NONE, CompressionType.ZSTD, CompressionType.LZ4])
    with base.path.open("rb") as f, out.open("wb") as g:
        reader = make_reader(f)
        profile = reader.get_header().profile
        w = Writer(g, compression=kind, chunk_size=rng.choice([512, 4096, 1 << 20]))
        w.start(profile=profile, library="bag_fuzz")
        schemas, channels = {}, {}
        for schema, channel, msg in reader.iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(
                    channel.topic, channel.message_encoding,
                    schemas.get(channel.schema_id, 0), channel.metadata,
                )  # fmt: skip
            w.add_message(channels[channel.id], msg.log_time, msg.data, msg.publish_time,
                          msg.sequence)  # fmt: skip
        w.finish()
    return out.read_bytes()


def mutate(base: Base, rng: random.Random, work: Path) -> tuple[str, bytes]:
    """One mutation of ``base``'s bytes: ``(what was done, the new bytes)``."""
    data = bytearray(base.data)
    is_mcap = base.data.startswith(MCAP_MAGIC)
    kinds = [m for m in MUTATIONS if is_mcap or m not in ("record", "recompress")]
    kind = rng.choice(kinds)
    n = len(data)
    if kind == "recompress":
        data = bytearray(_recompress(base, rng, work / "recompressed.mcap"))
        n = len(data)
        if rng.random() < 0.5:
            return "recompress", bytes(data)
        kind = "recompress+flip"
    if kind in ("flip", "recompress+flip"):
        at = [rng.randrange(n) for _ in range(rng.randint(1, 8))]
        for i in at:
            data[i] ^= rng.randint(1, 255)
        return f"{kind} {at}", bytes(data)
    if kind == "garble":
        i, k = rng.randrange(n), rng.randint(16, 300)
        data[i : i + k] = rng.randbytes(len(data[i : i + k]))
        return f"garble {k} at {i}", bytes(data)
    if kind == "cut":
        i = rng.randrange(n)
        return f"cut at {i}", bytes(data[:i])
    if kind in ("duplicate", "delete"):
        i = rng.randrange(n)
        k = rng.randint(1, min(4096, n - i))
        if kind == "delete":
            return f"delete {k} at {i}", bytes(data[:i] + data[i + k :])
        return f"duplicate {k} at {i}", bytes(data[: i + k] + data[i : i + k] + data[i + k :])
    records = _records(base.data)
    i, k = rng.choice(records)
    return f"record at {i} duplicated", bytes(data[: i + k] + data[i : i + k] + data[i + k :])


def _same(a: list, b: list) -> bool:
    return len(a) == len(b) and all(
        x[2] == y[2] and np.array_equal(x[0], y[0]) and np.array_equal(x[1], y[1])
        for x, y in zip(a, b, strict=True)
    )


def run_case(base: Base, seed: int, work: Path) -> tuple[str, str]:
    """Mutate ``base`` with ``seed`` into ``work`` and read it: ``(outcome, what was done)``
    where the outcome is ``refused``, ``exact``, ``read differently`` (allowed only for a
    format without checksums) or ``FINDING: ...`` (the property broken)."""
    rng = random.Random(f"{base.name}/{seed}")
    what, data = mutate(base, rng, work)
    target = work / base.path.name
    if base.path.is_dir():
        import shutil

        shutil.rmtree(target, ignore_errors=True)
        shutil.copytree(base.path, target)
        _payload(target).write_bytes(data)
    else:
        target.write_bytes(data)
    try:
        frames = read_all(target)
    except SlimsegError as e:
        if "\n" in str(e) or not str(e):
            return f"FINDING: a refusal of {len(str(e).splitlines())} lines", what
        return "refused", what
    except Exception as e:  # the property: nothing but SlimsegError may leave a reader
        return f"FINDING: {type(e).__name__}: {str(e)[:200]}", what
    if _same(frames, base.frames):
        return "exact", what
    stamps = [t for _, _, t in frames]
    if stamps != sorted(stamps) or len(set(stamps)) != len(stamps):
        return "FINDING: frames out of order", what
    if base.checked:
        return f"FINDING: {len(frames)} frames read, not exactly the base's", what
    return "read differently", what


def fuzz(
    bases: list[Base], cases: int, work: Path, first_seed: int = 0, log: object = None
) -> tuple[Counter, list[tuple[str, int, str, str]]]:
    """``cases`` cases spread over ``bases`` (seeds from ``first_seed``): the outcome counts
    and the findings ``(base, seed, outcome, what was done)``."""
    counts: Counter = Counter()
    findings = []
    for k in range(cases):
        base = bases[k % len(bases)]
        seed = first_seed + k // len(bases)
        outcome, what = run_case(base, seed, work)
        counts[outcome if not outcome.startswith("FINDING") else "finding"] += 1
        if outcome.startswith("FINDING"):
            findings.append((base.name, seed, outcome, what))
            if log is not None:
                print(f"{base.name} seed {seed}: {outcome} ({what})", file=log, flush=True)
    return counts, findings


def main() -> int:
    """The long run: ``python tests/bag_fuzz.py --cases 100000 [--seed N] [--work DIR]``."""
    import logging
    import tempfile

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=100_000)
    ap.add_argument("--seed", type=int, default=1_000, help="first seed (CI uses 0 up)")
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--memory-gb", type=float, default=3.0, help="address-space cap")
    args = ap.parse_args()
    logging.disable(logging.CRITICAL)
    cap = int(args.memory_gb * (1 << 30))
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))  # an allocation bomb: MemoryError
    work = args.work or Path(tempfile.mkdtemp(prefix="bag_fuzz_"))
    bases = make_bases(work, make_sequence(work / "seq"))
    (work / "cases").mkdir(exist_ok=True)
    start, done, total = time.time(), 0, Counter()
    findings: list = []
    while done < args.cases:
        n = min(140 * len(bases), args.cases - done)
        counts, found = fuzz(bases, n, work / "cases", args.seed + done // len(bases), sys.stdout)
        total.update(counts)
        findings += found
        done += n
        print(f"{done} cases, {time.time() - start:.0f} s: {dict(total)}", flush=True)
    print(f"done: {done} recordings, {len(findings)} findings", flush=True)
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
