"""The SLAM-facing masking options shared by ``slimseg dynamic`` and ``slimseg slam-eval``:
``--preset papers|slimseg`` and one flag per setting of
:class:`slimseg.dynamic.masking_settings.MaskingSettings` (a flag overrides the preset)."""

from __future__ import annotations

import argparse

from slimseg.dynamic.masking_settings import DEFAULT_PRESET, PRESETS, MaskingSettings, preset

# flag -> (field, type, help)
FLAGS: dict[str, tuple[str, type, str]] = {
    "--conf": ("conf", float, "detector score threshold for masking (not predict's)"),
    "--dilation": ("dilation_px", int, "px added around every mask before keypoints are judged"),
    "--min-static": ("min_static", int, "Eq. 1: static points needed"),
    "--m-th-start": ("m_th_start", float, "Eq. 1: starting mobility threshold"),
    "--m-th-step": ("m_th_step", float, "Eq. 1: threshold step"),
    "--frame-ratio": ("frame_ratio", float, "Eq. 3: fraction of points on mobile objects"),
    "--t-o": ("t_o", float, "Eq. 4: seg-mask / box coverage above which the seg mask is kept"),
    "--rule": (
        "rule",
        str,
        "when static support runs short: eq1 (raise the threshold, then "
        "give up the frame) or degrade (give up the least certain masks first)",
    ),
    "--cut-behind": (
        "cut_behind_m",
        float,
        "metres behind its object's near depth from which mask pixels are cut (0: off)",
    ),
    "--keep-score": (
        "keep_score",
        float,
        "degrade: a mover scoring this or more is never given up",
    ),
    "--motion-odds": (
        "motion_odds",
        float,
        "seg/fusion: odds by which the epipolar check's moving/static decision weighs on an "
        "object's mobility prior (1: no check)",
    ),
    "--motion-layer": (
        "motion_layer_px",
        int,
        "with depth: keep what moved in behind an object's near layer when it covers this "
        "many px (0: off; needs the camera's intrinsics)",
    ),
    "--still-frames": (
        "still_frames",
        int,
        "with depth: an object whose depth has not changed against the frames this many and "
        "half as many back is static (0: off; needs the camera's intrinsics)",
    ),
}


def add_masking_args(p: argparse.ArgumentParser) -> None:
    """Add ``--preset`` and the per-setting flags (all defaulting to the preset's value)."""
    g = p.add_argument_group("masking settings (docs/slam_defaults.md)")
    values = "; ".join(
        f"{name}: " + ", ".join(f"{k}={v}" for k, v in s.as_dict().items())
        for name, s in PRESETS.items()
    )
    g.add_argument(
        "--preset",
        choices=tuple(PRESETS),
        default=DEFAULT_PRESET,
        help=f"named masking settings (default {DEFAULT_PRESET}); {values}",
    )
    for flag, (field, kind, text) in FLAGS.items():
        base = getattr(PRESETS[DEFAULT_PRESET], field)
        g.add_argument(flag, dest=field, type=kind, default=None,
                       help=f"{text} (default: the preset's, {DEFAULT_PRESET} {base})")  # fmt: skip


def masking_from_args(args: argparse.Namespace) -> MaskingSettings:
    """The preset with every given flag applied (validated: ``SettingsError`` names a bad one)."""
    given = {f: getattr(args, f) for f, _, _ in FLAGS.values() if getattr(args, f) is not None}
    return preset(args.preset).with_values(**given)
