"""``slimseg.Masker``: the per-frame masking chain configured from an exported model.

    with slimseg.Masker.from_onnx("m.onnx", track=True, rate="thread") as masker:
        for rgb, depth in frames:                       # RGB uint8 [H, W, 3], depth metres
            out = masker.step(rgb, depth)               # out.mask: uint8 [H, W], 255 = dynamic

The chain is :class:`~slimseg.dynamic.frame_masker.FrameMasker` (what every slimseg command
runs); this class adds its construction from a model file: the class mobility priors and the
recommended masking settings (``slam_masking``, or one of its named presets) come from the
export's metadata, explicit arguments override them. docs/runtime_api.md.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from slimseg.deploy.calibrated import expectation, is_calibrated, uncalibrated_note
from slimseg.deploy.metadata import masking_from_metadata
from slimseg.deploy.predictor import Predictor
from slimseg.dynamic.chain_config import ChainConfig, TrackPlan
from slimseg.dynamic.frame_masker import FrameMasker, segmenter_for
from slimseg.dynamic.model_rate import EVERY_FRAME, ModelRate
from slimseg.dynamic.modes import FPS, KEYPOINTS, Mode
from slimseg.dynamic.track_settings import DEFAULT_TRACK_PRESET, TrackSettings, track_preset
from slimseg.errors import SlimsegError

log = logging.getLogger(__name__)


class Masker(FrameMasker):
    """:class:`FrameMasker` around a :class:`~slimseg.deploy.predictor.Predictor`; build it
    with :meth:`from_onnx` (any model file :meth:`Predictor.from_path` loads) or
    :meth:`from_predictor`. ``predictor``: the model it runs; ``names``: its class names."""

    @classmethod
    def from_onnx(
        cls,
        path: str | Path,
        *,
        threads: int | None = None,
        backend: str = "auto",
        **options: Any,
    ) -> Masker:
        """Load ``path`` (``.onnx``; ``.pt`` / ``.ckpt`` weights work too) on ``threads``
        intra-op threads with ``backend`` (``onnxruntime``, ``openvino`` at f32,
        ``openvino:bf16``, ...: :meth:`Predictor.from_path`) and build the chain; ``options``:
        those of :meth:`from_predictor`."""
        return cls.from_predictor(Predictor.from_path(path, backend, threads=threads), **options)

    @classmethod
    def from_predictor(
        cls,
        predictor: Predictor,
        *,
        mode: Mode | str = Mode.FUSION,
        preset: str | None = None,
        track: bool | str | TrackSettings = False,
        rate: ModelRate | str = EVERY_FRAME,
        keypoints: int = KEYPOINTS,
        camera: tuple[float, float, float, float] | None = None,
        epipolar_depth: bool = False,
        fps: float = FPS,
        depth_scale: float | None = None,
        strict: bool = False,
        **masking: Any,
    ) -> Masker:
        """The chain for ``predictor``: ``mode`` (``fusion``, ``seg``, ``box``, ...);
        ``preset``: a named entry of the export's ``slam_masking.presets`` (default: its
        recommended settings); ``masking``: explicit overrides (``conf=0.2``, ``t_o=0.25``,
        ...); ``track``: the track stage (True: the default preset, a preset name, or
        settings); ``rate``: a :class:`ModelRate` or its text (``"3"``, ``"budget:25"``,
        ``"thread"``); ``strict``: refuse a setting that cannot act (no camera, a frame without
        depth) instead of saying so once; the rest as
        :class:`~slimseg.dynamic.chain_config.ChainConfig`."""
        settings = masking_from_metadata(predictor.metadata, preset)
        if preset is None and not is_calibrated(predictor.metadata):
            log.info("%s", uncalibrated_note(predictor.path))
        if masking:
            settings = settings.with_values(**masking)
        stage = _track_settings(track)
        if isinstance(rate, str):
            rate = ModelRate.parse(rate)
        config = ChainConfig(
            mode=mode, masking=settings, track=TrackPlan(stage, rate), keypoints=keypoints,
            camera=camera, epipolar_depth=epipolar_depth, fps=fps, depth_scale=depth_scale,
            strict=strict, expect=expectation(predictor.metadata, settings),
        )  # fmt: skip
        return cls(predictor, config)

    def __init__(self, predictor: Predictor, config: ChainConfig | None = None) -> None:
        """The chain running ``predictor`` (its class priors) as ``config`` says (None: the
        defaults; build through :meth:`from_predictor` to take the export's settings)."""
        super().__init__(segmenter_for(predictor), predictor.mobility, config)
        self.predictor = predictor

    @property
    def names(self) -> list[str]:
        """Class names (``objects.classes`` index them)."""
        return self.predictor.names


def _track_settings(track: bool | str | TrackSettings) -> TrackSettings | None:
    if isinstance(track, TrackSettings):
        return track
    if track is True:
        return track_preset(DEFAULT_TRACK_PRESET)
    if track is False or track is None:
        return None
    if isinstance(track, str):
        return track_preset(track)
    raise SlimsegError(f"track={track!r}: expected True/False, a preset name or TrackSettings")
