"""One configuration object for the per-frame chain (:class:`ChainConfig`), checked once.

Every knob of :class:`~slimseg.dynamic.frame_masker.FrameMasker` is a field here: the mode,
the masking settings (Eq. 1/3/4, rule, depth cut), the track stage and the model's rate
(:class:`TrackPlan`), the ORB features per frame, the camera, the frame rate, the depth
scale. A rate other than every frame needs the track stage: :class:`TrackPlan` says so, and
nowhere else does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from numbers import Integral

from slimseg.data.value_checks import check_intrinsics
from slimseg.dynamic.familiarity import Expectation
from slimseg.dynamic.masking_settings import DEFAULT, MaskingSettings
from slimseg.dynamic.model_rate import EVERY_FRAME, ModelRate
from slimseg.dynamic.modes import FPS, KEYPOINTS, MAX_KEYPOINTS, Mode, mode_of
from slimseg.dynamic.track_settings import TrackSettings, detection_floor
from slimseg.errors import SlimsegError


@dataclass(frozen=True)
class TrackPlan:
    """The track stage of a run: ``settings`` (None: off, the per-frame output) and the
    model's ``rate`` (:class:`~slimseg.dynamic.model_rate.ModelRate`). A rate other than every
    frame needs ``settings``: the tracks carry the masks over the frames without a result."""

    settings: TrackSettings | None = None
    rate: ModelRate = EVERY_FRAME

    def __post_init__(self) -> None:
        if self.settings is None and not self.rate.every_frame:
            raise SlimsegError(
                f"model rate '{self.rate.name}' needs the track stage (--track; track= in "
                "the API): the tracks carry the masks over the frames the model skips"
            )

    @property
    def on(self) -> bool:
        return self.settings is not None

    def floor(self, conf: float) -> float:
        """The score threshold the model must run at: the masking one, or BYTE's ``low``."""
        return detection_floor(conf, self.settings)

    def describe(self) -> str:
        if self.settings is None:
            return "off (per-frame)"
        rate = "" if self.rate.every_frame else f", {self.rate.describe()}"
        return f"{self.settings.describe()}{rate}"


TRACK_OFF = TrackPlan()
"""Every frame judged alone: the output of earlier versions, exactly."""


@dataclass(frozen=True)
class ChainConfig:
    """How the chain masks a stream: ``mode`` (a :class:`~slimseg.dynamic.modes.Mode` or its
    name); ``masking``: the settings (score threshold, dilation, Eq. 1/3/4, rule, depth cut);
    ``track``: the track stage and the model's rate; ``keypoints``: ORB features per frame;
    ``camera`` ``(fx, fy, cx, cy)``: the intrinsics, which the depth cut's motion layers need
    (:mod:`slimseg.dynamic.occupancy`); ``epipolar_depth``: the epipolar check also takes the
    previous depth (its PnP residual; needs ``camera``); ``fps``: the stream's rate (the
    stage's time constants); ``depth_scale``: units per metre of integer depth images (TUM:
    5000; float depth is metres); ``strict``: a setting that cannot act (its lever lacks the
    camera, or a frame lacks depth) is refused (``SlimsegError``) instead of said once;
    ``expect``: what the model's calibration measured (:mod:`slimseg.dynamic.familiarity`:
    masks far looser than that move the settings to the tighter evidence; None: no check)."""

    mode: Mode = Mode.FUSION
    masking: MaskingSettings = DEFAULT
    track: TrackPlan = field(default=TRACK_OFF)
    keypoints: int = KEYPOINTS
    camera: tuple[float, float, float, float] | None = None
    epipolar_depth: bool = False
    fps: float = FPS
    depth_scale: float | None = None
    strict: bool = False
    expect: Expectation | None = None

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "mode", mode_of(self.mode))
        except ValueError as e:
            raise SlimsegError(str(e)) from None
        ds = self.depth_scale
        if ds is not None and not (math.isfinite(ds) and ds > 0):
            raise SlimsegError(f"depth_scale {ds}: expected units per metre > 0")
        k = self.keypoints
        if isinstance(k, bool) or not isinstance(k, Integral) or not (1 <= k <= MAX_KEYPOINTS):
            raise SlimsegError(f"keypoints {k!r}: expected 1 to {MAX_KEYPOINTS} per frame")
        if self.camera is not None:
            if len(self.camera) != 4:
                raise SlimsegError(f"camera {self.camera!r}: expected (fx, fy, cx, cy)")
            names = ("fx", "fy", "cx", "cy")
            check_intrinsics(dict(zip(names, map(float, self.camera), strict=True)), "camera")
        if self.epipolar_depth and self.camera is None:
            raise SlimsegError("epipolar_depth needs the camera's intrinsics: pass camera=")
        fps = self.fps
        if (
            isinstance(fps, bool)
            or not isinstance(fps, int | float)
            or not (math.isfinite(fps) and fps > 0)
        ):
            raise SlimsegError(f"fps {fps!r}: expected the sequence's frames per second, > 0")

    @property
    def floor(self) -> float:
        """The score threshold the model runs at: the masking one, or BYTE's ``low``."""
        return self.track.floor(self.masking.conf)


DEFAULT_CHAIN = ChainConfig()
"""The chain's defaults: fusion, the shipped masking preset, every frame judged alone."""
