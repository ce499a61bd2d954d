"""The SLAM-facing masking settings, one home: score threshold, dilation, Eq. 1/3/4 parameters.

Two named presets (``docs/slam_defaults.md``):

- ``papers``: the values of the substation paper (docs/papers.md §2: Eq. 1 starts at 0.25 and
  steps by 0.1, Eq. 4's t_o = 0.25), our reading of its garbled Eq. 3 (5 %), the detector score
  threshold of a detection-style default (0.25, which the papers do not state) and no
  dilation (none is described);
- ``slimseg``: the defaults chosen from ``slimseg slam-eval --sweep`` on synthetic
  ``walking_xyz`` / ``walking_static`` sequences with ORB-SLAM3 (ATE vs each setting). A
  missed walker costs a SLAM system far more than a few static keypoints dropped, so the score
  threshold sits well below the detection-style one.

These are a separate family from the detection-style thresholds of ``slimseg.ops.nms``
(``PREDICT_CONF`` for ``predict``, ``EVAL_CONF`` for mAP): never one number serving both
(docs/conventions.md §6). ``slimseg dynamic``, ``slimseg slam-eval`` and the export metadata
read the ``slimseg`` preset from here.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

from slimseg.dynamic.degrade import KEEP_SCORE
from slimseg.dynamic.motion_evidence import MOTION_ODDS
from slimseg.dynamic.occupancy import MOTION_LAYER_PX
from slimseg.dynamic.seg_box import T_O
from slimseg.dynamic.stillness import STILL_FRAMES
from slimseg.dynamic.threshold import DYNAMIC_FRAME_RATIO, M_TH_START, M_TH_STEP
from slimseg.errors import SlimsegError
from slimseg.utils.value_ranges import Range, describe_values, in_range

# Frame width the dilation was chosen at (TUM / Bonn RGB-D frames are 640 x 480): a runtime on
# other frame sizes scales it by max(h, w) / DILATION_REFERENCE_PX.
DILATION_REFERENCE_PX = 640
# The detection-style default score threshold the papers' detectors ran with (YOLO's 0.25).
PAPERS_CONF = 0.25
# Eq. 1's "too few static points" is unspecified in the paper: the pipeline's long-standing 100.
PAPERS_MIN_STATIC = 100


class SettingsError(SlimsegError):
    """A masking setting out of its range (one line, naming the setting)."""


@dataclass(frozen=True)
class MaskingSettings:
    """How detections become a dynamic mask for SLAM.

    ``conf``: detector score threshold (keep detections scoring above it); ``dilation_px``:
    pixels added around every mask before keypoints are classified (frame pixels at a
    ``DILATION_REFERENCE_PX``-wide frame); ``min_static``: Eq. 1's static points needed;
    ``m_th_start`` / ``m_th_step``: Eq. 1's starting mobility threshold and its step;
    ``frame_ratio``: Eq. 3's fraction of points on mobile objects making a dynamic keyframe;
    ``t_o``: Eq. 4's seg-mask-to-box coverage above which the seg mask is kept; ``rule``:
    what happens when static support runs short, ``eq1`` (raise the mobility threshold, then
    give up the frame: the paper's Eq. 1) or ``degrade`` (give up the least certain masks one
    at a time, :mod:`slimseg.dynamic.degrade`); ``keep_score``: ``degrade`` never gives up a
    candidate scoring at least this; ``cut_behind_m``: with depth, mask pixels more than this
    many metres behind their object's near depth are cut (0: off,
    :mod:`slimseg.dynamic.depth_cut`); ``motion_odds``: seg and fusion modes, the odds by
    which an epipolar check's decision moves an object's mobility (1: no check,
    :mod:`slimseg.dynamic.motion_evidence`); ``motion_layer_px``: with depth, the previous
    frame's depth and the intrinsics, what moved in behind an object's near layer is kept when
    it covers at least this many frame pixels (0: off, :mod:`slimseg.dynamic.occupancy`);
    ``still_frames``: with depth and the intrinsics, an object whose depth has not changed
    against the frames this many and half as many back gets mobility 0 (0: off,
    :mod:`slimseg.dynamic.stillness`).
    """

    conf: float
    dilation_px: int
    min_static: int
    m_th_start: float
    m_th_step: float
    frame_ratio: float
    t_o: float
    rule: str
    keep_score: float
    cut_behind_m: float
    motion_odds: float
    motion_layer_px: int
    still_frames: int

    def __post_init__(self) -> None:
        for f in fields(self):
            check_value(f.name, getattr(self, f.name))

    def with_values(self, **values: float | str) -> MaskingSettings:
        """A copy with some fields replaced (validated)."""
        return replace(self, **values)

    def as_dict(self) -> dict[str, float | int | str]:
        return asdict(self)

    def describe(self) -> str:
        """``slimseg preset (conf 0.1, dilation_px 5, ...)``, or ``custom (...)``."""
        return describe_values(preset_name(self), self.as_dict())


# field -> (lowest, highest, integer, what it is); bounds inclusive except those listed below
RANGES: dict[str, Range] = {
    "conf": (0.0, 1.0, False, "detector score threshold, 0 <= conf < 1"),
    "dilation_px": (0, 200, True, "mask dilation in whole pixels, 0-200"),
    "min_static": (0, 100_000, True, "Eq. 1 static points, a whole number >= 0"),
    "m_th_start": (0.0, 1.0, False, "Eq. 1 starting threshold, 0-1"),
    "m_th_step": (0.0, 1.0, False, "Eq. 1 step, 0 < step <= 1"),
    "frame_ratio": (0.0, 1.0, False, "Eq. 3 fraction, 0-1"),
    "t_o": (0.0, 1.0, False, "Eq. 4 coverage threshold, 0-1"),
    "keep_score": (0.0, 1.0, False, "score from which the degrading rule keeps a mask, 0-1"),
    "cut_behind_m": (0.0, 100.0, False, "metres behind its object a mask pixel is cut, 0: off"),
    "motion_odds": (1.0, 1e6, False, "odds a motion check's decision weighs by, 1 (off) - 1e6"),
    "motion_layer_px": (0, 1_000_000, True, "pixels that make a motion layer, whole, 0: off"),
    "still_frames": (0, 1000, True, "frames an object must stand still, whole, 0: off"),
}
# what to do when static support runs short (docs/slam_defaults.md §1)
RULES = ("eq1", "degrade")
OPEN_LOW = ("m_th_step",)  # the lower bound itself is not allowed
OPEN_HIGH = ("conf",)


def check_value(name: str, value: object) -> None:
    """Raise :class:`SettingsError` unless ``value`` is valid for field ``name``."""
    if name == "rule":
        if value not in RULES:
            raise SettingsError(f"masking setting rule = {value!r}: expected one of {RULES}")
        return
    if not in_range(value, RANGES[name], name in OPEN_LOW, name in OPEN_HIGH):
        raise SettingsError(f"masking setting {name} = {value!r}: expected {RANGES[name][3]}")


PAPERS = MaskingSettings(
    conf=PAPERS_CONF,
    dilation_px=0,
    min_static=PAPERS_MIN_STATIC,
    m_th_start=M_TH_START,
    m_th_step=M_TH_STEP,
    frame_ratio=DYNAMIC_FRAME_RATIO,
    t_o=T_O,
    rule="eq1",
    keep_score=KEEP_SCORE,
    cut_behind_m=0.0,
    motion_odds=1.0,
    motion_layer_px=0,
    still_frames=0,
)
# Chosen from the sweeps of docs/slam_defaults.md.
# t_o 1 with cut_behind_m 0.5: on dynamic keyframes every detection's box cut to its depth
# layer replaces the 320-px seg mask (keypoint precision 36 -> 66 %, recall 81 -> 98 % on the
# demo's sequence); without depth that is the whole box: pass t_o 0.25 for RGB-only frames.
# motion_odds 10: objects of a class that may move, seen static, give their keypoints back (§5).
# motion_layer_px 100: a walker behind a nearer thing keeps its mask where it moved in (§5).
# still_frames 20: a person standing still for 20 frames gives its keypoints back (§5).
SLIMSEG = PAPERS.with_values(
    conf=0.1, dilation_px=5, t_o=1.0, rule="degrade", cut_behind_m=0.5, motion_odds=MOTION_ODDS,
    motion_layer_px=MOTION_LAYER_PX, still_frames=STILL_FRAMES,
)  # fmt: skip
PRESETS: dict[str, MaskingSettings] = {"papers": PAPERS, "slimseg": SLIMSEG}
DEFAULT_PRESET = "slimseg"
DEFAULT = PRESETS[DEFAULT_PRESET]


def preset(name: str) -> MaskingSettings:
    """The named preset, or :class:`SettingsError` listing the names."""
    if name not in PRESETS:
        raise SettingsError(f"unknown masking preset {name!r}; valid: {', '.join(PRESETS)}")
    return PRESETS[name]


def preset_name(settings: MaskingSettings) -> str | None:
    """The name of the preset equal to ``settings`` (None: a custom combination)."""
    return next((k for k, v in PRESETS.items() if v == settings), None)
