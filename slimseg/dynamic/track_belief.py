"""The track stage's moving probabilities: where the epipolar check's decisions go when the
track stage runs (:class:`~slimseg.dynamic.mobility.MotionBelief`). A decided check updates a
tracked object's ``p`` (the epipolar modes) or weighs its belief by the motion odds (seg and
fusion); an untracked object is judged as without tracking."""

from __future__ import annotations

import numpy as np

from slimseg.dynamic.motion_evidence import weigh_odds
from slimseg.dynamic.track import Tracker
from slimseg.objects import Objects


class TrackBeliefs:
    """The :class:`~slimseg.dynamic.mobility.MotionBelief` of a
    :class:`~slimseg.dynamic.track.Tracker`: reads and updates its tracks as they are."""

    def __init__(self, tracker: Tracker) -> None:
        self.tracker = tracker

    def observe_motion(
        self, frame: Objects, checked: list[int], decided: np.ndarray, moving: np.ndarray
    ) -> np.ndarray:
        """Feed the epipolar check's decisions on objects ``checked`` (indices into ``frame``)
        to their tracks' moving probability; returns the updated ``mobility float32 [M]``
        (an untracked object the check finds static gets 0, as without tracking)."""
        by_id = {t.id: t for t in self.tracker.tracks}
        mob = frame.mobility.copy()
        for k, dec, mov in zip(checked, decided, moving, strict=True):
            tid = int(frame.track_ids[k])
            t = by_id.get(tid)
            if not dec:
                continue
            if t is None:
                mob[k] = mob[k] if mov else 0.0
                continue
            t.p = (1 - self.tracker.s.p_alpha) * t.p + self.tracker.s.p_alpha * float(mov)
            mob[k] = t.mobility(self.tracker.s.coast_decay)
        return mob

    def beliefs(self, frame: Objects) -> np.ndarray:
        """``float32 [M]``: what is believed of each object's motion: its track's moving
        probability ``p`` (its emitted mobility is ``p`` times ``coast_decay`` per miss), the
        emitted mobility of an untracked one."""
        by_id = {t.id: t.p for t in self.tracker.tracks}
        ids = frame.track_ids.tolist()
        return np.array([by_id.get(int(i), m) for i, m in zip(ids, frame.mobility.tolist(),
                                                           strict=True)], np.float32)  # fmt: skip

    def weigh_motion(
        self,
        frame: Objects,
        checked: list[int],
        decided: np.ndarray,
        moving: np.ndarray,
        odds: float,
    ) -> np.ndarray:
        """The motion odds of the seg and fusion modes (:mod:`slimseg.dynamic.motion_evidence`)
        on the objects ``checked``: a decided check weighs the belief (:meth:`beliefs`), and
        a coasted mask keeps its decay on top, so a person (``p`` 1) is beyond argument while
        it coasts as while it is detected. ``p`` itself is not updated (the odds are this
        frame's evidence, as without the track stage). Returns ``mobility float32 [M]``."""
        belief = self.beliefs(frame)
        mob = frame.mobility.copy()
        for k, dec, mov in zip(checked, decided, moving, strict=True):
            if dec and 0.0 < belief[k] < 1.0:
                decay = self.tracker.s.coast_decay ** int(frame.misses[k])
                mob[k] = weigh_odds(float(belief[k]), bool(mov), odds) * decay
        return mob
