"""The track stage's inner records: one object it emits this frame (an :class:`Emitted` row,
gathered into the frame's :class:`~slimseg.objects.Objects`) and one object over time
(:class:`Track`). The logic that moves them is :class:`slimseg.dynamic.track.Tracker`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from slimseg.dynamic.kalman import BoxKalman
from slimseg.dynamic.mask_patch import Patch


@dataclass(frozen=True)
class Emitted:
    """One object the stage emits this frame (a row of its ``Objects``): ``box [4]``
    xyxy px, class ``cls``, its mask ``patch``, the ``mobility`` Eq. 1 uses, ``track_id`` (-1:
    untracked), ``source`` (det / coast / carried), ``misses``, detection ``score`` (0 for
    predicted masks), ``det_index`` among the frame's input detections (-1: predicted), and
    ``moved``: a late detection moved on from where the model saw it (its full-frame mask no
    longer applies)."""

    box: np.ndarray
    cls: int
    patch: Patch
    mobility: float
    track_id: int
    source: str
    misses: int = 0
    score: float = 0.0
    det_index: int = -1
    moved: bool = False


@dataclass
class Track:
    """One object over time (see the module docstring)."""

    id: int
    cls: int
    prior: float
    p: float
    kf: BoxKalman
    patch: Patch | None
    """last observed mask (None: box-only), in the frame it was observed"""
    transform: np.ndarray = field(default_factory=lambda: np.eye(3))
    """last-observed frame pixels → current frame pixels"""
    depth_m: float = 0.0
    """median depth under the last observed mask with valid depth (0: unknown)"""
    depth_frame: np.ndarray | None = None
    """depth image of the last observation, until :meth:`Tracker._depth` takes its median"""
    hits: int = 1
    misses: int = 0
    since_seen: int = 0
    confirmed: bool = False
    strong: bool = False
    """a detection scoring ``>= new`` backed it: only such tracks are confirmed (and coast);
    a weak track is carried over the frames the model skips and ends at its first miss"""
    dead: bool = False
    """a guard fired: the track is removed at the end of the frame"""
    predicted: Patch | None = None
    predicted_at: int = -1
    """the tracker's frame number ``predicted`` was computed for"""

    def mobility(self, decay: float) -> float:
        return self.p * decay**self.misses
