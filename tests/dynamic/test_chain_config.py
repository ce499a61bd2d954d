"""The chain's names and defaults have one home: the modes the C++ consumer parses are
:data:`~slimseg.dynamic.modes.CPP_MODES` under the same names, the rate check is written once,
and the per-frame record slices like an array."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from slimseg.dynamic.chain_config import ChainConfig, TrackPlan
from slimseg.dynamic.model_rate import ModelRate
from slimseg.dynamic.modes import CPP_MODES, MODES, Mode, mode_of
from slimseg.errors import SlimsegError
from slimseg.objects import SOURCE_COAST, Objects

ROOT = Path(__file__).resolve().parents[2]
CPP = ROOT / "export" / "cpp"


def test_the_cpp_consumer_parses_the_same_mode_names() -> None:
    """``parse_mode`` in rules.cpp accepts exactly the C++ modes' names, its enum has one
    value per mode, and its error message lists them."""
    src = (CPP / "src" / "rules.cpp").read_text()
    body = src[src.index("Mode parse_mode(") :]
    body = body[: body.index("\n}\n")]
    parsed = re.findall(r'name == "([^"]+)"', body)
    assert parsed == [m.value for m in CPP_MODES]
    header = (CPP / "include" / "slimseg" / "rules.hpp").read_text()
    (values,) = re.findall(r"enum class Mode \{([^}]*)\}", header)
    cpp_enum = [v.strip().lower() for v in values.split(",")]
    assert cpp_enum == [m.name.lower() for m in CPP_MODES]
    assert all(m.value in body for m in CPP_MODES)


def test_modes_are_one_enum() -> None:
    assert tuple(m.value for m in Mode) == MODES and set(CPP_MODES) <= set(Mode)
    assert mode_of("fusion") is Mode.FUSION and Mode.SEG == "seg"
    with pytest.raises(ValueError, match="mode 'boxes': expected one of seg, box"):
        mode_of("boxes")
    assert ChainConfig(mode="box").mode is Mode.BOX


def test_a_rate_needs_the_track_stage_is_said_once() -> None:
    """One place refuses a model rate without the track stage (TrackPlan), in one wording."""
    wording = "needs the track stage"
    homes = [p for p in (ROOT / "slimseg").rglob("*.py") if wording in p.read_text()]
    assert [p.name for p in homes] == ["chain_config.py"]
    with pytest.raises(SlimsegError, match=wording):
        ChainConfig(track=TrackPlan(None, ModelRate.every_n(2)))
    assert ChainConfig().track.rate.every_frame


def _objects() -> Objects:
    masks = np.zeros((3, 4, 5), bool)
    masks[1, 1:3, 1:4] = True
    return Objects(np.arange(12).reshape(3, 4), [0.9, 0.5, 0.1], [2, 0, 1], masks, (4, 5),
                   source=["det", SOURCE_COAST, "det"], misses=[0, 2, 0])  # fmt: skip


def test_objects_slice_like_arrays() -> None:
    o = _objects()
    assert len(o) == 3 and o.boxes.dtype == np.float32 and o.classes.dtype == np.int64
    assert o.track_ids.tolist() == [-1, -1, -1] and o.det_index.tolist() == [0, 1, 2]
    assert o.mobility is None and o.predicted.tolist() == [False, True, False]
    kept = o[o.scores > 0.3]
    assert kept.scores.tolist() == pytest.approx([0.9, 0.5]) and kept.masks.shape == (2, 4, 5)
    back = o[np.array([2, 1])]
    assert back.classes.tolist() == [1, 0] and back.masks[1].sum() == 6
    assert back.misses.tolist() == [0, 2] and back.hw == (4, 5)
    assert len(o[1:]) == 2 and len(o[np.zeros(3, bool)]) == 0 and len(o[1]) == 1
    assert o.priors(np.array([0.1, 0.2, 0.3])).tolist() == pytest.approx([0.3, 0.1, 0.2])
    empty = Objects.empty((4, 5))
    assert len(empty) == 0 and empty.masks.shape == (0, 4, 5)
    with pytest.raises(ValueError, match=r"masks \[3, 4, 5\]: expected \[2, H, W\]"):
        Objects(np.zeros((2, 4)), [1, 1], [0, 0], np.zeros((3, 4, 5), bool), (4, 5))


def test_the_record_is_torch_free() -> None:
    code = "import sys, slimseg.objects; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)  # fmt: skip
    assert out.stdout.strip() == "False"
