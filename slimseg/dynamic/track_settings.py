"""The track stage's knobs, one home: association thresholds, coasting, moving probability.

The stage (:mod:`slimseg.dynamic.track`, docs/tracking.md) sits between a frame's detections
and the masking logic. ``None`` everywhere a ``TrackSettings`` is optional means *off*: the
per-frame output of earlier versions, exactly.

Named presets:

- ``coast``: BYTE association, camera-motion-compensated prediction, confirmed tracks coast
  for ``max_coast`` = 3 frames (ByteTrack / BoT-SORT / CFP-SLAM's missed-detection
  compensation), a per-track moving probability where the epipolar check runs;
- ``no-coast``: the same association and moving probability, nothing emitted for a missed
  detection (the ladder's "tracks without coasting" rung: what association alone changes).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

from slimseg.dynamic.knobs import BY_KEY, KnobError, preset_values
from slimseg.utils.value_ranges import describe_values

# The stage's constants: never swept, the same in every preset (docs/tracking.md §2).
CONFIRM_SCORE = 0.5
"""a new track backed by a detection scoring at least this is confirmed at once"""
MIN_HITS = 2
"""matches that confirm a strong track otherwise"""
IOU_HIGH = 0.3
"""the first BYTE pass's mask IoU gate (box IoU for box-only models)"""
IOU_LOW = 0.5
"""the second pass's gate"""
MIN_DEPTH_SHARE = 0.3
"""a coasted track ends when less than this share of its mask lies inside its depth band"""
MAX_OUTSIDE = 0.5
"""... or more than this share of its predicted box has left the image"""
KEEP_FRAMES = 15
"""model frames an unmatched track is remembered"""
P_RELAX_S = 1.0
"""seconds in which a moving probability relaxes to its class prior between observations"""


class TrackSettingsError(KnobError):
    """A track setting out of its range (one line, naming the setting)."""


_COAST = preset_values("coast")


@dataclass(frozen=True)
class TrackSettings:
    """How detections become tracks and tracks become masks (docs/tracking.md §2); the knobs
    of :data:`slimseg.dynamic.knobs.KNOBS` (group ``track``), the rest module constants.

    Association (BYTE): detections scoring ``>= high`` are matched first against every track,
    then those in ``[low, high)`` against the confirmed tracks still unmatched; a match needs
    a mask IoU (box IoU for box-only models) of at least :data:`IOU_HIGH` / :data:`IOU_LOW`.
    An unmatched detection that is emitted (above the masking threshold) or scores
    ``>= new`` opens a tentative track; one backed by a detection scoring ``>= new`` is
    confirmed after :data:`MIN_HITS` matches (at once when it scores ``>=
    CONFIRM_SCORE``); a tentative track ends at its first model frame without a match.

    Coasting: a confirmed track without a match emits its predicted mask for up to
    ``max_coast`` frames (0: never), dilated by ``coast_dilate_px`` per missed frame; its
    mobility is multiplied by ``coast_decay`` per miss. Pixels of a coasted mask farther than
    ``depth_band_m`` from the track's depth are dropped, and the track ends when less than
    :data:`MIN_DEPTH_SHARE` of them remain or more than :data:`MAX_OUTSIDE` of its predicted
    box has left the image. A track unmatched for :data:`KEEP_FRAMES` model frames is
    forgotten.

    Own motion: a late model result (the model on its own thread) is moved into the current
    frame, and every track's mask from one frame to the next, by the object's own motion:
    the median of at least ``own_matches`` ORB matches on its mask
    (:mod:`slimseg.dynamic.object_motion`); with fewer (or ``own_matches`` 0) by the camera
    motion and then the track's velocity.

    Moving probability: ``p <- (1 - p_alpha) p + p_alpha s`` with ``s`` = 1 (the epipolar
    check says moving) or 0 (static), no update while undecided; between observations ``p``
    relaxes to the class prior with time constant :data:`P_RELAX_S` seconds.
    """

    high: float = _COAST["high"]
    low: float = _COAST["low"]
    new: float = _COAST["new"]
    max_coast: int = _COAST["max_coast"]
    coast_decay: float = _COAST["coast_decay"]
    coast_dilate_px: int = _COAST["coast_dilate_px"]
    depth_band_m: float = _COAST["depth_band_m"]
    p_alpha: float = _COAST["p_alpha"]
    own_matches: int = _COAST["own_matches"]

    def __post_init__(self) -> None:
        for f in fields(self):
            check_track_value(f.name, getattr(self, f.name))
        if self.low > self.high:
            raise TrackSettingsError(
                f"track setting low = {self.low} above high = {self.high}: low-score "
                "detections are those between low and high"
            )

    def with_values(self, **values: float) -> TrackSettings:
        """A copy with some fields replaced (validated)."""
        return replace(self, **values)

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)

    def describe(self) -> str:
        """``coast preset (high 0.25, ...)`` or ``custom (...)``."""
        name = next((k for k, v in TRACK_PRESETS.items() if v == self), None)
        return describe_values(name, self.as_dict())


def check_track_value(name: str, value: object) -> None:
    """Raise :class:`TrackSettingsError` unless ``value`` is valid for field ``name``."""
    try:
        BY_KEY[name].check(value)
    except KnobError as e:
        raise TrackSettingsError(f"track {e}") from None


COAST = TrackSettings()
NO_COAST = COAST.with_values(max_coast=0)
TRACK_PRESETS: dict[str, TrackSettings] = {"coast": COAST, "no-coast": NO_COAST}
DEFAULT_TRACK_PRESET = "coast"


def detection_floor(conf: float, track: TrackSettings | None) -> float:
    """The score threshold the model must run at: the masking ``conf``, or with the stage on
    BYTE's ``low`` when lower (its second pass uses detections down to it)."""
    return conf if track is None else min(conf, track.low)


def track_preset(name: str) -> TrackSettings:
    """The named preset, or :class:`TrackSettingsError` listing the names."""
    if name not in TRACK_PRESETS:
        valid = ", ".join(TRACK_PRESETS)
        raise TrackSettingsError(f"unknown track preset {name!r}; valid: {valid}")
    return TRACK_PRESETS[name]
