"""Does the model behave as its calibration saw it? The chain compares the masks it makes with
what the calibration measured, and leans on the tighter evidence when they are far looser.

A calibration (``slimseg calibrate``) records, for the chosen settings, the mean share of the
frame the masks covered and the mean share of keypoints left static on its sequences
(:class:`Expectation`). On a robot the scene or the model may differ from what it was
calibrated on: masks covering far more of the frame (a model firing on walls in a new room)
leave a SLAM engine too little static structure. Over the first :data:`WINDOW` frames the
chain measures the same two shares; when the masks cover more than :data:`LOOSER` times the
expected share, or the static support falls below :data:`SUPPORT` times the expected, it says
so once and moves every setting to the tighter of the calibrated and the shipped values
(:func:`tighter`): a higher score threshold, less dilation, the closer depth cut, more weight
on the epipolar evidence, more static support demanded. Masks covering under :data:`TIGHTER`
of the expected share are far *tighter* (a scene where the model scores walkers lower than on
its calibration sequences, e.g. a rotating camera): said once too, and the recall knobs move to
the looser of the two (:func:`looser`: the lower score threshold, the wider dilation, the
lower mover threshold), since a missed walker costs a SLAM engine more than a few static
keypoints.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from slimseg.dynamic.masking_settings import MaskingSettings

log = logging.getLogger(__name__)

#: Frames measured before the comparison is made (once).
WINDOW = 30
#: Masks covering more than this multiple of the calibrated share are "far looser".
LOOSER = 2.0
#: Static keypoint support below this fraction of the calibrated share is "far looser" too.
SUPPORT = 0.5
#: Masks covering less than this fraction of the calibrated share are "far tighter".
TIGHTER = 0.25


@dataclass(frozen=True)
class Expectation:
    """What a calibration measured under its chosen settings: the mean share of the frame
    masked and the mean share of keypoints left static; ``fallback``: the settings whose
    tighter values the chain moves to (the shipped defaults)."""

    mask_share: float
    static_share: float
    fallback: MaskingSettings


def frame_shares(mask: np.ndarray, dynamic: np.ndarray) -> tuple[float, float]:
    """One frame's share of ``mask uint8 [H, W]`` masked and share of keypoints left static
    (``dynamic bool [N]``; 1 without keypoints): what a calibration records
    (:class:`Expectation`) and what the chain compares with it, one definition for both."""
    static = 1.0 - float(np.mean(dynamic)) if len(dynamic) else 1.0
    return float(np.count_nonzero(mask)) / max(mask.size, 1), static


def looser(a: MaskingSettings, b: MaskingSettings) -> MaskingSettings:
    """Each recall knob at the looser of ``a``'s and ``b``'s values (the rest as ``a``): the
    lower score threshold, the wider dilation, the lower mover threshold of Eq. 1."""
    return a.with_values(
        conf=min(a.conf, b.conf),
        dilation_px=max(a.dilation_px, b.dilation_px),
        m_th_start=min(a.m_th_start, b.m_th_start),
    )


def tighter(a: MaskingSettings, b: MaskingSettings) -> MaskingSettings:
    """Each knob at the tighter of ``a``'s and ``b``'s values (the rest as ``a``): the higher
    score threshold, the lower dilation, the closer depth cut (an active cut before none),
    the higher motion odds, the more static support and the higher never-give-up score."""
    cuts = [v for v in (a.cut_behind_m, b.cut_behind_m) if v > 0]
    return a.with_values(
        conf=max(a.conf, b.conf),
        dilation_px=min(a.dilation_px, b.dilation_px),
        cut_behind_m=min(cuts) if cuts else 0.0,
        motion_odds=max(a.motion_odds, b.motion_odds),
        min_static=max(a.min_static, b.min_static),
        keep_score=max(a.keep_score, b.keep_score),
    )


class Familiarity:
    """Watches the chain's first :data:`WINDOW` frames against ``expect``; :meth:`observe`
    returns the settings to switch to when the masks are far looser than expected (once)."""

    def __init__(self, expect: Expectation, settings: MaskingSettings) -> None:
        self.expect = expect
        self.settings = settings
        self.frames = 0
        self._masked = 0.0
        self._static = 0.0
        self.verdict: str | None = None
        """None until judged; then ``familiar``, ``looser`` or ``tighter``"""

    def observe(self, mask: np.ndarray, dynamic: np.ndarray) -> MaskingSettings | None:
        """Count one frame's ``mask uint8 [H, W]`` and ``dynamic bool [N]`` (per keypoint);
        after :data:`WINDOW` frames judge once. Returns the tighter settings to use from the
        next frame on, or None."""
        if self.verdict is not None:
            return None
        self.frames += 1
        share, static = frame_shares(mask, dynamic)
        self._masked += share
        self._static += static
        if self.frames < WINDOW:
            return None
        share, static = self._masked / self.frames, self._static / self.frames
        e = self.expect
        far_looser = share > LOOSER * max(e.mask_share, 1e-3) or static < SUPPORT * e.static_share
        if far_looser:
            self.verdict = "looser"
            new = tighter(self.settings, e.fallback)
            log.warning(
                "the masks over the first %d frames cover %.1f %% of the frame (calibration: "
                "%.1f %%) and leave %.1f %% of keypoints static (calibration: %.1f %%): far "
                "looser than this model's calibration; the tighter of its calibrated and the "
                "shipped settings from now on (%s)", self.frames, 100 * share,
                100 * e.mask_share, 100 * static, 100 * e.static_share, new.describe(),
            )  # fmt: skip
            return new if new != self.settings else None
        if share < TIGHTER * e.mask_share:
            self.verdict = "tighter"
            new = looser(self.settings, e.fallback)
            log.warning(
                "the masks over the first %d frames cover %.1f %% of the frame, far less than "
                "this model's calibration saw (%.1f %%): walkers may go unmasked; the looser "
                "of its calibrated and the shipped recall settings from now on (%s)",
                self.frames, 100 * share, 100 * e.mask_share, new.describe(),
            )  # fmt: skip
            return new if new != self.settings else None
        self.verdict = "familiar"
        return None
