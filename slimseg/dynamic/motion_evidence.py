"""Motion evidence on an object's mobility: the epipolar check's decision as a likelihood, not a
verdict.

A class prior (Eq. 1's mobility: person 1.0, dog 0.75, chair 0.25, tv 0) says how likely an
object of that class moves before anything about this frame is known. The epipolar check
(:func:`slimseg.dynamic.epipolar.check_motion`: the object's matched ORB points against the
camera's motion from the previous frame) is evidence on it. This module weighs it by Bayes'
rule in odds form: a decided object's odds ``p / (1 - p)`` are multiplied by ``odds`` when the
check finds it moving and divided by ``odds`` when it finds it static; undecided objects (too
few matched points, the first frame) keep their prior.

So a prior of 1 (a person) or 0 (a tv) cannot be argued with: a standing person stays masked,
as the papers' masking wants; a dog the check sees static for a frame (0.75 → 0.23 at odds 10)
falls under Eq. 1's starting threshold (0.25) and gives its static keypoints back; a chair
being pushed (0.25 → 0.77) joins the mask. VTD-SLAM's epipolar modes instead set every object
found static to 0, people included (``semantic+epipolar``, ``fusion+epipolar``): their recall
falls wherever the check errs on a person.
"""

from __future__ import annotations

import numpy as np

from slimseg.dynamic.knobs import shipped

# The odds a decided check multiplies (moving) or divides (static) a mobility's odds by: 10
# turns the synthetic world's static dogs and balls (prior 0.75) to 0.23 on a static decision,
# under Eq. 1's starting threshold (docs/slam_defaults.md §5). 1: the check is not run.
MOTION_ODDS = shipped("motion_odds")


def uncertain(mobility: np.ndarray) -> np.ndarray:
    """``bool [M]``: the objects whose mobility evidence can change (0 < p < 1)."""
    mob = np.asarray(mobility, np.float32)
    return (mob > 0) & (mob < 1)


def weigh_motion(
    mobility: np.ndarray,
    checked: list[int],
    decided: np.ndarray,
    moving: np.ndarray,
    odds: float = MOTION_ODDS,
) -> np.ndarray:
    """``mobility float32 [M]`` with the check's decisions on the objects ``checked`` (indices;
    ``decided`` / ``moving`` ``bool [len(checked)]``) applied in odds form → ``float32 [M]``
    (a new array; undecided and unchecked objects unchanged)."""
    out = np.asarray(mobility, np.float32).copy()
    for k, dec, mov in zip(checked, decided, moving, strict=True):
        p = float(out[k])
        if not dec or p <= 0.0 or p >= 1.0:
            continue
        out[k] = weigh_odds(p, bool(mov), odds)
    return out


def weigh_odds(p: float, moving: bool, odds: float) -> float:
    """One mobility ``0 < p < 1`` after a decided check: its odds times ``odds`` (moving)
    or divided by them (static)."""
    ratio = odds if moving else 1.0 / odds
    return p * ratio / (p * ratio + 1.0 - p)
