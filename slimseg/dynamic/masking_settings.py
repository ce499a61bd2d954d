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
read the ``slimseg`` preset from here. Each field's range, help and preset values live in
:data:`slimseg.dynamic.knobs.KNOBS` (the table of docs/settings.md).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

from slimseg.dynamic.knobs import BY_KEY, MASKING_PRESETS, KnobError, Rule, preset_values
from slimseg.utils.value_ranges import describe_values

# Frame width the dilation was chosen at (TUM / Bonn RGB-D frames are 640 x 480): a runtime on
# other frame sizes scales it by max(h, w) / DILATION_REFERENCE_PX.
DILATION_REFERENCE_PX = 640


class SettingsError(KnobError):
    """A masking setting out of its range (one line, naming the setting)."""


@dataclass(frozen=True)
class MaskingSettings:
    """How detections become a dynamic mask for SLAM; one field per masking knob of
    :data:`slimseg.dynamic.knobs.KNOBS` (its help says what each does, docs/settings.md lists
    them).

    ``conf``: detector score threshold (keep detections scoring above it); ``dilation_px``:
    pixels added around every mask before keypoints are classified (frame pixels at a
    ``DILATION_REFERENCE_PX``-wide frame); ``min_static``: Eq. 1's static points needed;
    ``m_th_start`` / ``m_th_step``: Eq. 1's starting mobility threshold and its step;
    ``frame_ratio``: Eq. 3's fraction of points on mobile objects making a dynamic keyframe;
    ``t_o``: Eq. 4's seg-mask-to-box coverage above which the seg mask is kept; ``rule``
    (:class:`~slimseg.dynamic.knobs.Rule`): what happens when static support runs short;
    ``keep_score``: ``degrade`` never gives up a candidate scoring at least this;
    ``cut_behind_m``: with depth, mask pixels more than this many metres behind their
    object's near depth are cut (0: off, :mod:`slimseg.dynamic.depth_cut`); ``motion_odds``:
    seg and fusion modes, the odds by which an epipolar check's decision moves an object's
    mobility (1: no check, :mod:`slimseg.dynamic.motion_evidence`); ``motion_layer_px``: with
    depth, the previous frame's depth and the intrinsics, what moved in behind an object's
    near layer is kept when it covers at least this many frame pixels (0: off,
    :mod:`slimseg.dynamic.occupancy`); ``still_frames``: with depth and the intrinsics, an
    object whose depth has not changed against the frames this many and half as many back
    gets mobility 0 (0: off, :mod:`slimseg.dynamic.stillness`).
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
        object.__setattr__(self, "rule", Rule(self.rule))

    def with_values(self, **values: float | str) -> MaskingSettings:
        """A copy with some fields replaced (validated)."""
        return replace(self, **values)

    def as_dict(self) -> dict[str, float | int | str]:
        """``{field: value}``, plain types (the rule as its name)."""
        return {k: str(v) if isinstance(v, Rule) else v for k, v in asdict(self).items()}

    def describe(self) -> str:
        """``slimseg preset (conf 0.1, dilation_px 5, ...)``, or ``custom (...)``."""
        return describe_values(preset_name(self), self.as_dict())

    def inert(self, key: str) -> bool:
        """Does the knob ``key`` change nothing under these settings' ``rule``
        (``m_th_step`` under ``degrade``, ``keep_score`` under ``eq1``)?"""
        rule = BY_KEY[key].rule
        return rule is not None and rule != self.rule


def check_value(name: str, value: object) -> None:
    """Raise :class:`SettingsError` unless ``value`` is valid for field ``name``."""
    try:
        BY_KEY[name].check(value)
    except KnobError as e:
        raise SettingsError(f"masking {e}") from None


PRESETS: dict[str, MaskingSettings] = {
    name: MaskingSettings(**preset_values(name)) for name in MASKING_PRESETS
}
"""``papers``: the equations as printed; ``slimseg``: chosen from the sweeps of
docs/slam_defaults.md (values and reasons: docs/settings.md)."""
PAPERS = PRESETS["papers"]
SLIMSEG = PRESETS["slimseg"]
DEFAULT_PRESET = "slimseg"
CALIBRATED = "calibrated"
"""The name of a model's own preset, which ``slimseg calibrate`` writes into its export's
metadata (:mod:`slimseg.deploy.calibrated`): not one of :data:`PRESETS`, it lives in the model."""
DEFAULT = PRESETS[DEFAULT_PRESET]


def preset(name: str) -> MaskingSettings:
    """The named preset, or :class:`SettingsError` listing the names."""
    if name not in PRESETS:
        raise SettingsError(f"unknown masking preset {name!r}; valid: {', '.join(PRESETS)}")
    return PRESETS[name]


def preset_name(settings: MaskingSettings) -> str | None:
    """The name of the preset equal to ``settings`` (None: a custom combination)."""
    return next((k for k, v in PRESETS.items() if v == settings), None)
