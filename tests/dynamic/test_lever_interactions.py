"""Every lever of the shipped preset at once, with the track stage: no lever undoes another.

Each lever has its own test; these run them together where a missed detection makes them
meet. The case that went unseen: with the preset's motion odds (10), the seg and fusion modes
weighed the epipolar check on the mobility a coasted walker is *emitted* with (its track's
probability times ``coast_decay`` per miss, 0.7 after one), so one "static" decision on the
coasted mask dropped it under Eq. 1's threshold and the track stage's gain was argued away
(keypoint recall 81.9 % with ``--track`` against 100 % with the odds off, on the sequence
below). The odds now weigh the track's belief; its coast decay stays on top.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from slimseg.data.synth.sequence import write_sequence
from slimseg.dynamic.annotations import AnnotationInstances, Dropout
from slimseg.dynamic.chain_config import ChainConfig, TrackPlan
from slimseg.dynamic.masking_settings import DEFAULT
from slimseg.dynamic.track_settings import COAST
from slimseg.sequence.sequence_run import run_sequence


@pytest.fixture(scope="module")
def bursty(tmp_path_factory) -> tuple[Path, AnnotationInstances]:
    """A held-out walking_halfsphere sequence whose ground-truth instances lose each walker
    in bursts of 3 frames, 30 % of its frames."""
    root = tmp_path_factory.mktemp("levers") / "seq"
    write_sequence(root, seed=402, index=0, frames=40, size=(320, 240),
                   preset="walking_halfsphere")  # fmt: skip
    return root, AnnotationInstances(root, Dropout(0.3, 3, seed=0))


@pytest.mark.parametrize("mode", ["seg", "fusion"])
def test_track_stage_keeps_its_coasted_walkers_under_every_lever(
    bursty: tuple[Path, AnnotationInstances], tmp_path: Path, mode: str
) -> None:
    seq, instances = bursty
    assert instances.dropped > 0
    levers = DEFAULT  # depth cut, motion odds, motion layers, stillness, the degrading rule
    assert levers.motion_odds > 1 and levers.still_frames > 0 and levers.motion_layer_px > 0
    off = run_sequence(
        instances, seq, tmp_path / "off", ChainConfig(mode=mode, masking=levers), progress=False
    )
    on = run_sequence(
        instances,
        seq,
        tmp_path / "on",
        ChainConfig(mode=mode, masking=levers, track=TrackPlan(COAST)),
        progress=False,
    )
    alone = run_sequence(
        instances,
        seq,
        tmp_path / "alone",
        ChainConfig(mode=mode, masking=levers.with_values(motion_odds=1.0), track=TrackPlan(COAST)),
        progress=False,
    )
    r_off, r_on, r_alone = (r.scores[mode].recall for r in (off, on, alone))
    assert r_off < 0.9, r_off  # the dropouts cost recall without the stage
    assert r_on >= 0.9, (r_off, r_on, r_alone)  # the stage wins them back with every lever on
    assert r_on >= r_alone - 0.02, (r_on, r_alone)  # and the odds take nothing of it away
