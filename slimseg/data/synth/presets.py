"""Camera paths and walkers modelled on the TUM RGB-D dynamic-object sequences.

The default sequences (no preset) move the camera a few centimetres past 1-3 walkers: enough
for keypoint-level scoring, too little for a trajectory error to mean anything. A preset
replaces the camera path and the walkers (the room and the static objects stay those of the
seed), after TUM fr3's sequences:

- ``walking_xyz``: the camera translates back and forth along x, y and z by tens of
  centimetres with little rotation; two or three people walk close by (1.6-2.6 m), covering
  10-30 % of the frame at times;
- ``walking_static``: the same people, a camera that barely moves (≤ 2 cm);
- ``walking_halfsphere``: the camera sweeps a half-sphere-like arc (x/y/z tens of cm) while
  turning (yaw ≈ ±0.15 rad) towards the room;
- ``sitting_static``: a barely moving camera and two people who shift in place (slow, short
  paces) rather than cross the room — the TUM "sitting" sequences' small motions;
- ``walking_rpy``: a camera held at one spot (x/y/z ≤ 5 cm) that rotates fast about all
  three axes — yaw ±15-25°, pitch ±10-17°, roll ±12-20°, each at 0.3-0.45 Hz: angular speed
  peaks of about 60-80 °/s, 45-50 °/s on average — while two or three people walk close by
  as in ``walking_xyz``, each passing the middle of the view at its own time in the sequence
  (the walkers of the other presets start anywhere in their loop). Pitch and roll exist only
  in this preset's poses.

Motion blur (:mod:`slimseg.data.synth.blur`): every preset (and the default sequences) takes
an exposure time, ``slimseg data synth --exposure-ms MS`` (0 = no blur). Its default is the
preset's ``exposure_ms``: 20 ms (60 % of the 33 ms frame interval, an indoor auto-exposure)
for ``walking_rpy``, 0 for the others, whose files stay byte for byte what they were. Only the
RGB frames (``rgb/``, ``background/rgb/``) are blurred; depth, the ``dynamic/`` masks and
``annotations.json`` keep the sharp instant of the frame's timestamp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slimseg.errors import SlimsegError

Range = tuple[float, float]


@dataclass(frozen=True)
class Preset:
    """Per-axis ``(amplitude m or rad, frequency Hz)`` ranges of the sinusoidal camera path
    (axes ``x, y, z, yaw`` and optionally ``pitch, roll``), walker count, distance and speed
    ranges; ``pace_m``: None = cross the whole view, else walk back and forth over this many
    metres around a spot near the centre; ``in_view``: each walker passes the middle of the
    view at its own time (else it starts anywhere in its loop); ``exposure_ms``: the default
    shutter time of the motion blur (0: none)."""

    motion: dict[str, tuple[Range, Range]]
    walkers: tuple[int, int]
    walker_z: Range
    speed: Range
    pace_m: float | None = None
    in_view: bool = False
    exposure_ms: float = 0.0


_STILL = {
    "x": ((0.005, 0.015), (0.1, 0.3)),
    "y": ((0.002, 0.008), (0.1, 0.3)),
    "z": ((0.005, 0.015), (0.1, 0.3)),
    "yaw": ((0.002, 0.008), (0.1, 0.3)),
}
PRESETS: dict[str, Preset] = {
    "walking_xyz": Preset(
        motion={
            "x": ((0.25, 0.35), (0.08, 0.12)),
            "y": ((0.08, 0.14), (0.10, 0.16)),
            "z": ((0.15, 0.25), (0.06, 0.10)),
            "yaw": ((0.02, 0.05), (0.05, 0.10)),
        },
        walkers=(2, 3),
        walker_z=(1.6, 2.6),
        speed=(0.5, 1.0),
    ),
    "walking_static": Preset(_STILL, walkers=(2, 3), walker_z=(1.6, 2.6), speed=(0.5, 1.0)),
    "walking_halfsphere": Preset(
        motion={
            "x": ((0.25, 0.35), (0.06, 0.10)),
            "y": ((0.10, 0.18), (0.12, 0.18)),
            "z": ((0.10, 0.20), (0.12, 0.18)),
            "yaw": ((0.12, 0.18), (0.06, 0.10)),
        },
        walkers=(2, 3),
        walker_z=(1.6, 2.6),
        speed=(0.5, 1.0),
    ),
    "sitting_static": Preset(
        _STILL, walkers=(2, 2), walker_z=(1.6, 2.4), speed=(0.1, 0.25), pace_m=0.5
    ),
    "walking_rpy": Preset(
        motion={
            "x": ((0.02, 0.05), (0.1, 0.3)),
            "y": ((0.01, 0.03), (0.1, 0.3)),
            "z": ((0.02, 0.05), (0.1, 0.3)),
            "yaw": ((0.26, 0.44), (0.30, 0.45)),
            "pitch": ((0.17, 0.30), (0.30, 0.45)),
            "roll": ((0.21, 0.35), (0.30, 0.45)),
        },
        walkers=(2, 3),
        walker_z=(1.6, 2.6),
        speed=(0.5, 1.0),
        in_view=True,
        exposure_ms=20.0,
    ),
}


def default_exposure_ms(name: str | None) -> float:
    """The motion-blur shutter time (ms) of preset ``name`` when none is given (None: the
    default sequences, 0). Raises ``SlimsegError`` for an unknown name."""
    if name is None:
        return 0.0
    if name not in PRESETS:
        raise SlimsegError(f"unknown sequence preset {name!r}; valid: {sorted(PRESETS)}")
    return PRESETS[name].exposure_ms


def preset_motion(
    preset: Preset, rng: np.random.Generator
) -> dict[str, tuple[float, float, float]]:
    """Sample ``axis → (amplitude, frequency Hz, phase rad)`` for :func:`camera_pose`."""
    return {
        axis: (
            float(rng.uniform(*amp)),
            float(rng.uniform(*freq)),
            float(rng.uniform(0, 2 * np.pi)),
        )
        for axis, (amp, freq) in preset.motion.items()
    }
