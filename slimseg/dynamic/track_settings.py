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

from slimseg.errors import SlimsegError
from slimseg.utils.value_ranges import Range, describe_values, in_range


class TrackSettingsError(SlimsegError):
    """A track setting out of its range (one line, naming the setting)."""


@dataclass(frozen=True)
class TrackSettings:
    """How detections become tracks and tracks become masks (docs/tracking.md §2).

    Association (BYTE): detections scoring ``>= high`` are matched first against every track,
    then those in ``[low, high)`` against the confirmed tracks still unmatched; a match needs
    a mask IoU (box IoU for box-only models) of at least ``iou_high`` / ``iou_low``. An
    unmatched detection that is emitted (above the masking threshold) or scores ``>= new``
    opens a tentative track; one backed by a detection scoring ``>= new`` is confirmed after
    ``min_hits`` matches (at once when it scores ``>= confirm``); a tentative track ends at
    its first model frame without a match.

    Coasting: a confirmed track without a match emits its predicted mask for up to
    ``max_coast`` frames (0: never), dilated by ``coast_dilate_px`` per missed frame; its
    mobility is multiplied by ``coast_decay`` per miss. Pixels of a coasted mask farther than
    ``depth_band_m`` from the track's depth are dropped, and the track ends when less than
    ``min_depth_share`` of them remain or more than ``max_outside`` of its predicted box has
    left the image. A track unmatched for ``keep_frames`` model frames is forgotten.

    Own motion: a late model result (the model on its own thread) is moved into the current
    frame, and every track's mask from one frame to the next, by the object's own motion:
    the median of at least ``own_matches`` ORB matches on its mask
    (:mod:`slimseg.dynamic.object_motion`); with fewer (or ``own_matches`` 0) by the camera
    motion and then the track's velocity.

    Moving probability: ``p <- (1 - p_alpha) p + p_alpha s`` with ``s`` = 1 (the epipolar
    check says moving) or 0 (static), no update while undecided; between observations ``p``
    relaxes to the class prior with time constant ``p_relax_s`` seconds.
    """

    high: float = 0.25
    low: float = 0.05
    new: float = 0.25
    confirm: float = 0.5
    min_hits: int = 2
    iou_high: float = 0.3
    iou_low: float = 0.5
    max_coast: int = 3
    coast_decay: float = 0.7
    coast_dilate_px: int = 2
    depth_band_m: float = 0.4
    min_depth_share: float = 0.3
    max_outside: float = 0.5
    keep_frames: int = 15
    p_alpha: float = 0.3
    p_relax_s: float = 1.0
    own_matches: int = 6

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


# field -> (lowest, highest, integer, what it is), bounds inclusive
TRACK_RANGES: dict[str, Range] = {
    "high": (0.0, 1.0, False, "first-pass score threshold, 0-1"),
    "low": (0.0, 1.0, False, "second-pass score threshold, 0-1"),
    "new": (0.0, 1.0, False, "score that opens a strong track (one that can coast), 0-1"),
    "confirm": (0.0, 1.0, False, "score that confirms a new track at once, 0-1"),
    "min_hits": (1, 100, True, "matches that confirm a track, a whole number >= 1"),
    "iou_high": (0.0, 1.0, False, "first-pass IoU gate, 0-1"),
    "iou_low": (0.0, 1.0, False, "second-pass IoU gate, 0-1"),
    "max_coast": (0, 1000, True, "frames a lost track's mask is emitted, a whole number >= 0"),
    "coast_decay": (0.0, 1.0, False, "mobility factor per missed frame, 0-1"),
    "coast_dilate_px": (0, 100, True, "px of dilation per missed frame, 0-100"),
    "depth_band_m": (0.0, 100.0, False, "depth band of a coasted mask in metres (0: off)"),
    "min_depth_share": (0.0, 1.0, False, "share of a coasted mask inside the band, 0-1"),
    "max_outside": (0.0, 1.0, False, "share of a predicted box outside the image, 0-1"),
    "keep_frames": (1, 10_000, True, "frames a lost track is remembered, a whole number >= 1"),
    "p_alpha": (0.0, 1.0, False, "moving-probability update weight, 0-1"),
    "p_relax_s": (0.0, 1e6, False, "relaxation time to the class prior in s (0: at once)"),
    "own_matches": (0, 10_000, True, "ORB matches that move a mask by its own motion, >= 0"),
}


def check_track_value(name: str, value: object) -> None:
    """Raise :class:`TrackSettingsError` unless ``value`` is valid for field ``name``."""
    if not in_range(value, TRACK_RANGES[name]):
        raise TrackSettingsError(
            f"track setting {name} = {value!r}: expected {TRACK_RANGES[name][3]}"
        )


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
