"""tools/per_pixel_stillness.py: a mask over a static wall is given back, the walkers' stay."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import cv2
import pytest

from slimseg.data.synth import generate
from slimseg.data.tum import TumSequence, mask_name

TOOL = Path(__file__).resolve().parents[2] / "tools" / "per_pixel_stillness.py"


def _tool():
    spec = importlib.util.spec_from_file_location("per_pixel_stillness", TOOL)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


def test_static_pixels_given_back(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "data"
    generate(out, 1, 1, 64, 0, sequences=1, frames=24, seq_size=(320, 240), progress=False,
             preset="walking_static")  # fmt: skip
    root = out / "sequences" / "seq_000"
    seq = TumSequence(root)
    masks = tmp_path / "dyn" / "masks"
    masks.mkdir(parents=True)
    for (stamp, _), _ in seq.frames:  # the walkers plus the wall's top band (static)
        m = cv2.imread(str(root / "dynamic" / mask_name(stamp)), cv2.IMREAD_GRAYSCALE)
        m[:40] = 255
        cv2.imwrite(str(masks / mask_name(stamp)), m)
    assert _tool().main([str(root), str(tmp_path / "dyn"), str(tmp_path / "new")]) == 0
    lines = capsys.readouterr().out.splitlines()
    (before_p, before_r), (after_p, after_r) = (
        [float(v.split()[-1].rstrip("%,")) for v in line.split(": ")[1].split(", ")]
        for line in lines
    )
    assert after_p > before_p and after_r >= before_r - 10  # the wall back, the walkers kept
    last = mask_name(seq.frames[-1][0][0])
    new = cv2.imread(str(tmp_path / "new" / "masks" / last), cv2.IMREAD_GRAYSCALE) > 0
    assert new[5:35].mean() < 0.5  # most of the band given back in the last frame
    assert _tool().main([str(root), str(tmp_path / "dyn"), str(tmp_path / "new")]) == 2
