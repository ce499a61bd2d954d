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
  paces) rather than cross the room — the TUM "sitting" sequences' small motions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

Range = tuple[float, float]


@dataclass(frozen=True)
class Preset:
    """Per-axis ``(amplitude m or rad, frequency Hz)`` ranges of the sinusoidal camera path,
    walker count, distance and speed ranges; ``pace_m``: None = cross the whole view, else
    walk back and forth over this many metres around a spot near the centre."""

    motion: dict[str, tuple[Range, Range]]
    walkers: tuple[int, int]
    walker_z: Range
    speed: Range
    pace_m: float | None = None


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
}


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
