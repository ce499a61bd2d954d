"""An object's mobility, decided in one place: its base (class prior, or its track's),
then the stillness test, then the epipolar check's evidence.

1. **Base**: the class prior (Eq. 1's mobility: person 1.0, dog 0.75, chair 0.25, tv 0), or
   with the track stage the track's moving probability times ``coast_decay`` per missed frame
   (the ``mobility`` column of the frame's :class:`~slimseg.objects.Objects`).
2. **Stillness**: an object the stillness test found still (``FrameInputs.still``,
   :mod:`slimseg.dynamic.stillness`) gets mobility 0 in every mode: static structure. It is
   then no candidate of the check, and its points stay static background for it.
3. **Evidence** (:func:`epipolar_evidence`: the object's matched ORB points against the
   camera's motion from the previous frame): in the epipolar modes (VTD-SLAM) a verdict, an
   object found static gets 0; in ``seg`` / ``fusion`` with ``motion_odds`` > 1 a likelihood
   weighed on the uncertain mobilities in odds form (:mod:`slimseg.dynamic.motion_evidence`).
   With the track stage the decisions go to the tracks (:class:`MotionBelief`): the verdict
   updates each track's moving probability, the odds weigh its belief, not its coast-decayed
   emission.

:func:`decide_mobility` is the only entry point of the check in the chain; the rules
(:mod:`slimseg.dynamic.pipeline`) take its :class:`Decision`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from slimseg.dynamic.epipolar import EpipolarResult, OrbFeatures, check_motion
from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.modes import EPIPOLAR_MODES, WEIGHED_MODES, Mode
from slimseg.dynamic.motion_evidence import uncertain, weigh_motion
from slimseg.objects import Objects


class MotionBelief(Protocol):
    """Where the check's decisions go with the track stage on
    (:class:`~slimseg.dynamic.track_belief.TrackBeliefs`): each returns the frame's
    ``mobility float32 [M]``."""

    def beliefs(self, frame: Objects) -> np.ndarray: ...

    def observe_motion(
        self, frame: Objects, checked: list[int], decided: np.ndarray, moving: np.ndarray
    ) -> np.ndarray: ...

    def weigh_motion(
        self,
        frame: Objects,
        checked: list[int],
        decided: np.ndarray,
        moving: np.ndarray,
        odds: float,
    ) -> np.ndarray: ...


@dataclass(frozen=True)
class MotionEvidence:
    """An epipolar check's ``result`` on the objects ``checked`` (indices into the frame's
    objects); ``result`` None: nothing was checked (first frame, no candidates)."""

    result: EpipolarResult | None
    checked: list[int]


@dataclass(frozen=True)
class Decision:
    """The mobility Eq. 1 uses, ``float32 [M]``, and the ``evidence`` it was decided on
    (None: no check ran)."""

    mobility: np.ndarray
    evidence: MotionEvidence | None = None

    @property
    def verdict(self) -> tuple[EpipolarResult | None, list[int]]:
        """The check's result and the objects it checked (``(None, [])`` without one)."""
        if self.evidence is None:
            return None, []
        return self.evidence.result, list(self.evidence.checked)


def decide_mobility(
    inputs: FrameInputs,
    mode: Mode,
    base: np.ndarray,
    *,
    mover_prior: float,
    motion_odds: float,
    belief: MotionBelief | None = None,
) -> Decision:
    """The mobility of ``inputs``' objects in ``mode`` (see the module docstring) from their
    ``base float32 [M]`` (class priors, or the tracks' mobility column); ``mover_prior``: the
    mobility above which an object is a candidate of the epipolar modes' check;
    ``motion_odds``: the odds of ``seg`` / ``fusion`` (1: no check); ``belief``: the track
    stage's tracks (None: per-frame)."""
    frame = inputs.objects
    mob = _still_zero(base, inputs.still)  # standing still: static structure
    if frame.masks is None or inputs.previous is None:
        return Decision(mob)
    if mode in EPIPOLAR_MODES:
        ev = epipolar_evidence(inputs, mob, mover_prior)
        if ev.result is None:
            return Decision(mob, ev)
        r = ev.result
        if belief is not None:
            after = belief.observe_motion(frame, ev.checked, r.decided, r.moving)
            return Decision(_still_zero(after, inputs.still), ev)
        out = mob.copy()
        checked = np.asarray(ev.checked, int)
        out[checked[r.decided & ~r.moving]] = 0.0
        return Decision(out, ev)
    if mode in WEIGHED_MODES and motion_odds > 1:
        base = mob if belief is None else _still_zero(belief.beliefs(frame), inputs.still)
        if not uncertain(base).any():
            return Decision(mob)
        ev = epipolar_evidence(inputs, np.where(uncertain(base), base, 0.0), 0.0)
        if ev.result is None:
            return Decision(mob, ev)
        r = ev.result
        if belief is None:
            return Decision(weigh_motion(mob, ev.checked, r.decided, r.moving, motion_odds), ev)
        after = belief.weigh_motion(frame, ev.checked, r.decided, r.moving, motion_odds)
        return Decision(_still_zero(after, inputs.still), ev)
    return Decision(mob)


def _still_zero(mob: np.ndarray, still: np.ndarray | None) -> np.ndarray:
    """``mob [M]`` with the objects found still (``still bool [M]``) at 0."""
    if still is None or not still.any():
        return mob
    return np.where(still, np.float32(0.0), mob).astype(mob.dtype)


def epipolar_evidence(
    inputs: FrameInputs, mob: np.ndarray, dynamic_mobility: float
) -> MotionEvidence:
    """Run the epipolar check on the objects whose mobility ``mob [M]`` exceeds
    ``dynamic_mobility``, on the chain's own ORB features (``inputs.matches``: the frame
    pair's matches when the track stage already computed them)."""
    candidates = np.flatnonzero(mob > dynamic_mobility)
    previous = inputs.previous
    if previous is None or len(candidates) == 0:
        return MotionEvidence(None, [])
    if inputs.descriptors is None:
        raise ValueError(
            "epipolar modes need the ORB descriptors of the keypoints: pass descriptors= "
            "(epipolar.orb_features gives keypoints and descriptors together)"
        )
    current = OrbFeatures(np.asarray(inputs.keypoints, np.float32).reshape(-1, 2),
                          inputs.descriptors)  # fmt: skip
    result = check_motion(
        previous.features,
        current,
        np.asarray(inputs.objects.masks, bool)[candidates],
        depth_m=previous.depth_m if previous.depth_residual else None,
        camera=previous.camera,
        pairs=inputs.matches,
    )
    return MotionEvidence(result, candidates.tolist())
