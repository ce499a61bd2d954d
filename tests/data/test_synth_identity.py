"""Byte-identity of the synthetic dataset: every file ``slimseg data synth`` writes is pinned.

A small still dataset with the default sequences, then one run per sequence preset, all from
fixed seeds through the CLI; the SHA-256 of every written file (RGB and depth PNGs, dynamic
masks, background frames, annotations.json, rgb.txt, depth.txt, groundtruth.txt, camera.yaml,
data.yaml) must equal the digest pinned in ``tests/reference/synth_digests.json``. No written
file embeds a time or the output path. Every file is hashed whole except data.yaml, hashed
without its ``#`` comment lines: they spell out the command line that regenerates the set,
whose wording is not an output of the renderer. Beside the files, the patch that ``draw``
paints for sampled styles of every category (and walking poses of the person) is pinned too.

The digests hold for one OpenCV/zlib and numpy and any x86-64 CPU with AVX2, with or without
AVX-512: the renderer avoids float32 transcendentals, whose numpy result depends on the CPU (on
AVX-512 numpy's float32 ``**`` is SVML's, elsewhere libm's). While ``finish_rgb``'s gamma was a
float32 power, pins made on an AVX-512 machine failed on an AVX2 one: 6 values one level off
(12 of 372 files, one value in 12,288 pixels each, each within one float32 ulp of a .5
rounding boundary). The float64 power is robust: moving every power result by 4 ulps changes
no output value (the float32 power: 32 of 3.8 million values per ulp), nor does moving every
float64 sin, cos, tan, exp, log and arctan2 by one ulp. These digests were pinned on an AVX2
CPU (numpy 2.4, OpenCV 5.1). OpenCV's float kernels (GaussianBlur, remap, resize) have no
AVX-512 code and run the same AVX2 code on both kinds; without AVX2 (``OPENCV_CPU_DISABLE=
AVX2,FMA3``) 5 files change by one value. Re-pin only for an intended output change:
``python tests/data/test_synth_identity.py`` rewrites the JSON.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from slimseg.cli import data_synth
from slimseg.data.synth import CATEGORIES, sample_style, walking_pose
from slimseg.data.synth.presets import PRESETS
from slimseg.data.synth.shapes import draw
from slimseg.utils.outputs import MANIFEST

REFERENCE = Path(__file__).parents[1] / "reference" / "synth_digests.json"
# Seed 1 gives default sequences with 3 and 1 walkers and a standing (static) person, and
# preset sequences with 3 and 2 walkers.
SEED = "1"
COMMON = ["--seed", SEED, "--frames", "4", "--seq-size", "128", "96", "--quiet"]
RUNS: dict[str, list[str]] = {
    "still": ["--train", "4", "--val", "2", "--imgsz", "96", "--sequences", "2", *COMMON],
    **{
        name: ["--train", "1", "--val", "1", "--imgsz", "64", "--sequences", "2", "--preset", name]
        + COMMON
        for name in sorted(PRESETS)
    },
}


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _write_runs(root: Path) -> None:
    parser = argparse.ArgumentParser()
    data_synth.add_parser(parser.add_subparsers(dest="command"))
    for name, argv in RUNS.items():
        args = parser.parse_args(["synth", "--out", str(root / name), *argv])
        assert args.run(args) == 0


def _draw_digests() -> dict[str, str]:
    """Digest of ``draw``'s patch (offset, ``rgb`` ``uint8 [h, w, 3]``, ``mask`` ``uint8
    [h, w]``) for three sampled styles per category and four gait phases of one walker."""
    out = {}
    for cat in CATEGORIES:
        for k in range(3):
            style = sample_style(cat.name, np.random.default_rng([17, cat.id, k]))
            out[f"draw/{cat.name}/{k}"] = style
    walker = sample_style("person", np.random.default_rng(5))
    for k in range(4):
        out[f"draw/walker/{k}"] = walker.with_params(**walking_pose(k * np.pi / 2, 0.45))
    digests = {}
    for key, style in out.items():
        patch = draw(style, 40.3, 52.7, 70.0, 96, 112)
        assert patch is not None
        head = np.array([patch.x0, patch.y0, *patch.mask.shape], np.int64).tobytes()
        digests[key] = _sha(head + patch.rgb.tobytes() + patch.mask.tobytes())
    return digests


def compute_digests(root: Path) -> dict[str, str]:
    """Write every run under ``root``; ``relative path -> SHA-256`` of each file (the output
    manifests aside: they only list the files), plus the ``draw/...`` patch digests."""
    _write_runs(root)
    files = sorted(p for p in root.rglob("*") if p.is_file() and p.name != MANIFEST)
    digests = {p.relative_to(root).as_posix(): _sha(_content(p)) for p in files}
    return digests | _draw_digests()


def _content(path: Path) -> bytes:
    """The bytes that are pinned: the whole file, except data.yaml's ``#`` comment lines
    (they spell out the regenerating command line, whose wording may change)."""
    data = path.read_bytes()
    if path.name != "data.yaml":
        return data
    return b"".join(ln for ln in data.splitlines(keepends=True) if not ln.startswith(b"#"))


@pytest.mark.filterwarnings("ignore:__array__ implementation:DeprecationWarning")
def test_synth_outputs_match_pinned_digests(tmp_path: Path) -> None:
    want = json.loads(REFERENCE.read_text())
    got = compute_digests(tmp_path)
    assert sorted(got) == sorted(want), {
        "missing": sorted(set(want) - set(got))[:10],
        "unexpected": sorted(set(got) - set(want))[:10],
    }
    changed = sorted(k for k in want if got[k] != want[k])
    assert not changed, f"{len(changed)} of {len(want)} outputs changed, e.g. {changed[:10]}"
    # the pinned sequences really show their walkers (non-empty dynamic masks) in every run
    for name in RUNS:
        for seq in ("seq_000", "seq_001"):
            masks = (tmp_path / name / "sequences" / seq / "dynamic").glob("*.png")
            assert any(cv2.imread(str(m), cv2.IMREAD_UNCHANGED).any() for m in masks), (name, seq)


if __name__ == "__main__":  # re-pin after an intended output change
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        pinned = compute_digests(Path(d))
    REFERENCE.write_text(json.dumps(pinned, indent=1, sort_keys=True) + "\n")
    print(f"pinned {len(pinned)} digests in {REFERENCE}", file=sys.stderr)
