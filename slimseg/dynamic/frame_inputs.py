"""What one frame brings to the masking chain (:class:`FrameInputs`): the record its stages
read (the objects' mobility is decided from it, :mod:`slimseg.dynamic.mobility`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slimseg.dynamic.epipolar import PreviousFrame
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
    matches: np.ndarray | None = None
    """the frame pair's ORB matches (:func:`~slimseg.dynamic.epipolar.match_features` rows,
    previous → these keypoints) when the track stage computed them: the check reuses them"""
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
