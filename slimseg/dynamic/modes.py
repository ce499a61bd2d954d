"""The masking modes and the chain's defaults: the one home of each name and number.

The C++ consumer (``export/cpp``: ``parse_mode`` in ``src/rules.cpp``) implements the
:data:`CPP_MODES` under the same names; ``tests/dynamic/test_chain_config.py`` reads its sources and
checks that they agree.
"""

from __future__ import annotations

from enum import StrEnum


class Mode(StrEnum):
    """How the frame's objects become the dynamic mask (``docs/slam_defaults.md``):

    ``seg``: instance masks with Eq. 1's adaptive mobility threshold; ``box``: the boxes of
    dynamic classes; ``fusion``: Eq. 4 (a thin seg mask replaced by its box) on Eq. 3's
    dynamic keyframes, then Eq. 1; ``box+depth-ransac``: YOLO-SLAM's depth-RANSAC inside the
    boxes; ``semantic+epipolar`` / ``fusion+epipolar``: ``seg`` / ``fusion`` after VTD-SLAM's
    epipolar check (an object found static keeps its points)."""

    SEG = "seg"
    BOX = "box"
    FUSION = "fusion"
    BOX_DEPTH_RANSAC = "box+depth-ransac"
    SEMANTIC_EPIPOLAR = "semantic+epipolar"
    FUSION_EPIPOLAR = "fusion+epipolar"


MODES: tuple[str, ...] = tuple(m.value for m in Mode)
"""Every mode's name, in :class:`Mode`'s order (the CLI's choices)."""
EPIPOLAR_MODES: dict[Mode, Mode] = {
    Mode.SEMANTIC_EPIPOLAR: Mode.SEG,
    Mode.FUSION_EPIPOLAR: Mode.FUSION,
}
"""An epipolar mode → the mode it runs after the check."""
WEIGHED_MODES = (Mode.SEG, Mode.FUSION)
"""Modes whose mobilities the epipolar check weighs on with ``motion_odds`` > 1."""
BOX_MODES = (Mode.BOX, Mode.BOX_DEPTH_RANSAC)
"""Modes that work without instance masks (a detection-only model)."""
CPP_MODES = (Mode.SEG, Mode.BOX, Mode.FUSION)
"""The modes the C++ consumer implements."""

KEYPOINTS = 1000
"""ORB features per frame (what ORB-SLAM extracts)."""
MAX_KEYPOINTS = 100_000
"""The most ORB features per frame the chain accepts: bounds the extractor."""
FPS = 30.0
"""Frames per second assumed where a source gives no rate (a folder of frames); the track
stage's time constants and a replay's pace follow it."""


def mode_of(name: str) -> Mode:
    """The :class:`Mode` called ``name``; ``ValueError`` listing the names otherwise."""
    try:
        return Mode(name)
    except ValueError:
        raise ValueError(f"mode {name!r}: expected one of {', '.join(MODES)}") from None
