"""What one frame brings to the masking rules (:class:`FrameInputs`) and the motion evidence
already weighed into it (:class:`MotionEvidence`): the record every stage of the chain reads."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slimseg.dynamic.epipolar import EpipolarResult, PreviousFrame
from slimseg.objects import Objects


@dataclass(frozen=True)
class FrameInputs:
    """What one frame brings, in frame pixels: ``keypoints float32 [N, 2]`` (x, y), the
    ``objects`` (:class:`~slimseg.objects.Objects`: boxes, classes, masks or None for a
    detector only, scores; with the track stage each one's mobility and whether its mask is a
    track's prediction); ``depth_m float32 [H, W]`` metres (depth-RANSAC, the depth cut);
    epipolar modes: ``descriptors uint8 [N, 32]`` (ORB, see ``epipolar.orb_features``) and
    the ``previous`` frame's features (None on the first frame: no check)."""

    keypoints: np.ndarray
    objects: Objects
    depth_m: np.ndarray | None = None
    descriptors: np.ndarray | None = None
    previous: PreviousFrame | None = None
    evidence: MotionEvidence | None = None
    """the epipolar check the track stage ran (its outcome is already in the mobilities)"""
    support: np.ndarray | None = None
    """``float32 [P, 2]`` corners the SLAM engine can take outside a mask (the ``degrade``
    rule's static support, :func:`slimseg.dynamic.degrade.support_points`; None: the
    keypoints)"""
    still: np.ndarray | None = None
    """``bool [M]``: the objects the stillness test found still, mobility 0 in every mode
    (:func:`slimseg.dynamic.stillness.find_still`; None: not tested)"""

    @property
    def hw(self) -> tuple[int, int]:
        """The frame's ``(H, W)``."""
        return self.objects.hw


@dataclass(frozen=True)
class MotionEvidence:
    """An epipolar check's ``result`` on the objects ``checked`` (indices into the frame's
    objects); ``result`` None: nothing was checked (first frame, no candidates)."""

    result: EpipolarResult | None
    checked: list[int]
    weighed: bool = False
    """the check's decisions were weighed in at the motion odds (seg, fusion), not applied
    as the epipolar modes' verdict"""
