"""What one TUM-style sequence shows: a static room and objects, walkers, a camera path.

The world is layered: a textured back wall and floor (``camera.Room``) and upright,
camera-facing object sprites standing on the floor. A pinhole camera moves slowly in x/y/z
and yaw (the ``walking_rpy`` preset: also fast in pitch and roll), so static objects move on
screen by amounts that depend on their depth (parallax).
Walkers (:func:`make_walker`) cross the room, or pace in place, articulating a side-view gait.
:mod:`slimseg.data.synth.sequence` renders and writes the frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from slimseg.data.synth.camera import Intrinsics, Pose, Room
from slimseg.data.synth.categories import BY_NAME, CATEGORIES
from slimseg.data.synth.person import walking_pose
from slimseg.data.synth.presets import PRESETS, default_exposure_ms, preset_motion
from slimseg.data.synth.scene import STREAM_SEQUENCE, Sensor, frame_rng, make_room
from slimseg.data.synth.shapes import sample_style
from slimseg.data.synth.style import Style
from slimseg.errors import SlimsegError

FPS = 30.0
STREAM_SEQUENCE_PRESET = STREAM_SEQUENCE + 2  # + 1: sequence.STREAM_SEQUENCE_NOISE


@dataclass
class Thing:
    """An upright object standing at world ``(x, bottom, z)``, ``height`` metres tall.

    Static things keep their pose. A walker paces back and forth along x over ``span`` metres
    centred on ``x`` (turning at the ends, so any sequence length keeps it coming back),
    at ``speed`` m/s, starting ``offset`` metres into its loop; its depth sways by ``sway``
    metres and it swings its limbs with ``cadence`` strides per second.
    """

    style: Style
    x: float
    z: float
    bottom: float
    height: float
    track_id: int
    moving: bool = False
    speed: float = 0.0
    span: float = 0.0
    offset: float = 0.0
    sway: float = 0.0
    cadence: float = 0.0
    phase: float = 0.0
    amplitude: float = 0.0

    def at(self, t: float) -> tuple[Style, np.ndarray]:
        """Style (pose) and bottom-centre world point at time ``t`` seconds."""
        if not self.moving:
            return self.style, np.array([self.x, self.bottom, self.z])
        s = (self.speed * t + self.offset) % (2 * self.span)
        heading = 1.0 if s < self.span else -1.0
        x = self.x - self.span / 2 + (s if s < self.span else 2 * self.span - s)
        z = self.z + self.sway * np.sin(2 * np.pi * t / 7.0 + self.phase)
        pose = walking_pose(self.phase + 2 * np.pi * self.cadence * t, self.amplitude)
        return self.style.with_params(flip=heading, **pose), np.array([x, self.bottom, z])


@dataclass
class World:
    """Everything fixed about one sequence (built by :func:`build_world`)."""

    k: Intrinsics
    room: Room
    things: list[Thing]
    sensor: Sensor
    motion: dict[str, tuple[float, float, float]]  # axis -> (amplitude, frequency Hz, phase)
    drift: tuple[float, float]  # (vx, vz) metres per second
    seed: int
    index: int
    frames: int
    meta: dict = field(default_factory=dict)
    exposure: float = 0.0  # seconds the shutter is open, centred on each frame; 0: no blur

    def pose(self, i: int) -> Pose:
        """Camera-to-world pose of frame ``i``."""
        return camera_pose(self.motion, self.drift, i / FPS)

    def pose_at(self, t: float) -> Pose:
        """Camera-to-world pose at time ``t`` seconds (frame ``i`` is at ``i / FPS``)."""
        return camera_pose(self.motion, self.drift, t)

    def exposure_poses(self, i: int) -> tuple[Pose, Pose, Pose]:
        """Frame ``i``'s poses at the shutter's opening, at its timestamp and at the closing."""
        t, half = i / FPS, self.exposure / 2
        return self.pose_at(t - half), self.pose(i), self.pose_at(t + half)


def camera_pose(
    motion: dict[str, tuple[float, float, float]], drift: tuple[float, float], t: float
) -> Pose:
    """Smooth camera path: a sinusoid per axis (``x, y, z, yaw`` and, if ``motion`` names
    them, ``pitch, roll``) plus a slow x/z drift."""
    val = {a: amp * np.sin(2 * np.pi * f * t + ph) for a, (amp, f, ph) in motion.items()}
    return Pose(
        x=float(val["x"] + drift[0] * t),
        y=float(val["y"]),
        z=float(val["z"] + drift[1] * t),
        yaw=float(val["yaw"]),
        pitch=float(val.get("pitch", 0.0)),
        roll=float(val.get("roll", 0.0)),
    )


def make_walker(
    rng: np.random.Generator,
    track_id: int,
    floor_y: float,
    half_fov: float,
    *,
    z_range: tuple[float, float],
    speed_range: tuple[float, float],
    max_sway: float,
    in_view_at: float | None = None,
    pace_m: float | None = None,
) -> Thing:
    """A walking person on the floor (``floor_y`` below the camera), drawn from ``rng``.

    Depth and speed are uniform in ``z_range`` (m) and ``speed_range`` (m/s), depth sway in
    ``[0, max_sway)`` m. ``pace_m`` None: it crosses the whole view (``half_fov`` = tan of half
    the horizontal field of view) from just outside one edge to outside the other; else it
    paces over ``pace_m`` metres around a spot near the centre. ``in_view_at`` (seconds): at
    that time it is in the central part of the view, heading either way; None: it starts
    anywhere in its loop. The draws' order is part of every seed's output: keep it.
    """
    z = float(rng.uniform(*z_range))
    speed = float(rng.uniform(*speed_range))
    x, span = 0.0, 2 * (z * half_fov + 0.5)
    if pace_m is not None:
        x, span = float(z * half_fov * rng.uniform(-0.5, 0.5)), pace_m
    offset = None
    if in_view_at is not None:
        s_mid = span * (rng.uniform(0.25, 0.75) + float(rng.integers(2)))
        offset = (s_mid - speed * in_view_at) % (2 * span)
    style = sample_style("person", rng).with_params(tilt=float(rng.normal(0, 0.03)))
    lo, hi = BY_NAME["person"].height_m
    height = float(rng.uniform(lo, hi))
    if offset is None:
        offset = float(rng.uniform(0, 2 * span))
    return Thing(
        style,
        x=x,
        z=z,
        bottom=floor_y,
        height=height,
        track_id=track_id,
        moving=True,
        speed=speed,
        span=span,
        offset=offset,
        sway=float(rng.uniform(0.0, max_sway)),
        cadence=speed / float(rng.uniform(1.1, 1.5)),
        phase=float(rng.uniform(0, 2 * np.pi)),
        amplitude=float(rng.uniform(0.35, 0.5)),
    )


def build_world(
    seed: int,
    index: int,
    frames: int,
    width: int = 640,
    height: int = 480,
    preset: str | None = None,
    exposure_ms: float | None = None,
) -> World:
    """Random room, 3-6 static objects (sometimes a standing person), 1-3 walkers, camera path.

    Deterministic in ``(seed, index, preset)``; ``frames`` only bounds the camera path (and,
    for a preset whose walkers are placed in view, when they are). ``preset`` (a
    :data:`~slimseg.data.synth.presets.PRESETS` name) replaces the camera path and the
    walkers; None keeps the default sequences byte for byte. ``exposure_ms``: the shutter time
    of the motion blur (:mod:`slimseg.data.synth.blur`); None: the preset's default (no
    preset: 0, no blur).
    """
    exposure = default_exposure_ms(preset) if exposure_ms is None else float(exposure_ms)
    if not 0.0 <= exposure <= 1000.0 / FPS:
        raise SlimsegError(f"exposure {exposure} ms: must be 0 to {1000.0 / FPS:.1f} ms")
    rng = frame_rng(seed, index, STREAM_SEQUENCE)
    k = Intrinsics.tum(width, height)
    duration = frames / FPS
    motion = {
        "x": (rng.uniform(0.03, 0.15), rng.uniform(0.05, 0.25), rng.uniform(0, 2 * np.pi)),
        "y": (rng.uniform(0.005, 0.03), rng.uniform(0.1, 0.5), rng.uniform(0, 2 * np.pi)),
        "z": (rng.uniform(0.01, 0.08), rng.uniform(0.05, 0.2), rng.uniform(0, 2 * np.pi)),
        "yaw": (rng.uniform(0.01, 0.06), rng.uniform(0.05, 0.2), rng.uniform(0, 2 * np.pi)),
    }
    slow = min(1.0, 4.0 / duration)  # total drift stays below ~0.5 m in long sequences
    drift = (float(rng.uniform(-0.12, 0.12) * slow), float(rng.uniform(-0.05, 0.05) * slow))
    floor_y = float(rng.uniform(0.8, 1.3))  # camera height above the floor
    wall_z = float(rng.uniform(4.8, 6.5))
    half_fov = k.cx / k.fx

    things: list[Thing] = []
    others = [c.name for c in CATEGORIES if c.name != "person"]
    n_static = int(rng.integers(3, 7))
    for j in range(n_static):
        name = "person" if j == 0 and rng.random() < 0.3 else others[int(rng.integers(len(others)))]
        lo, hi = BY_NAME[name].height_m
        style = sample_style(name, rng)
        z = float(rng.uniform(1.8, wall_z - 0.6))
        bottom = floor_y
        if name == "tv" and rng.random() < 0.5:  # wall-mounted
            z, bottom = wall_z - 0.1, floor_y - float(rng.uniform(0.9, 1.4))
        if name == "person":
            style = style.with_params(
                profile=0.0, tilt=0.0, arm_l1=-0.15, arm_l2=-0.1, arm_r1=0.15, arm_r2=0.1
            )
        x = float(z * half_fov * rng.uniform(-0.9, 0.9))
        things.append(Thing(style, x, z, bottom, float(rng.uniform(lo, hi)), track_id=j))
    for j in range(int(rng.integers(1, 4))):  # 1-3 crossing the view, in it at mid-sequence
        walker = make_walker(
            rng,
            n_static + j,
            floor_y,
            half_fov,
            z_range=(1.9, min(3.6, wall_z - 0.8)),
            speed_range=(0.5, 1.2),
            max_sway=0.3,
            in_view_at=duration / 2,
        )
        things.append(walker)
    if preset is not None:
        motion, drift = _apply_preset(
            preset, seed, index, things, n_static, floor_y, half_fov, duration
        )
    poses = [camera_pose(motion, drift, i / FPS) for i in range(frames)]
    room = make_room(rng, k, poses, wall_z, floor_y, clutter=0.6)
    sensor = Sensor(
        gain=tuple(float(g) for g in rng.uniform(0.85, 1.15) * rng.uniform(0.95, 1.05, 3)),
        bias=float(rng.uniform(-10, 10)),
        gamma=float(np.exp(rng.uniform(-0.15, 0.15))),
        blur=float(rng.uniform(0.0, 0.8)),
        noise=float(rng.uniform(1.0, 4.0)),
        depth_noise=float(rng.uniform(0.15, 0.5)),
        holes=int(rng.integers(0, 3)),
    )
    world = World(k, room, things, sensor, motion, drift, seed, index, frames)
    world.exposure = exposure / 1000.0
    if preset is not None:
        world.meta["preset"] = preset
    return world


def _apply_preset(
    name: str,
    seed: int,
    index: int,
    things: list[Thing],
    n_static: int,
    floor_y: float,
    half_fov: float,
    duration: float,
) -> tuple[dict[str, tuple[float, float, float]], tuple[float, float]]:
    """Replace the walkers in ``things`` (in place) and return the preset's camera path.

    The default walkers were drawn first all the same: the room and sensor that follow them
    in ``build_world``'s random stream stay those of the seed. With ``preset.in_view``,
    walker ``j`` of ``n`` is in the central part of the view at ``duration * (j + 0.5) / n``.
    """
    if name not in PRESETS:
        raise SlimsegError(f"unknown sequence preset {name!r}; valid: {sorted(PRESETS)}")
    preset = PRESETS[name]
    rng = frame_rng(seed, index, STREAM_SEQUENCE_PRESET)
    del things[n_static:]
    lo_n, hi_n = preset.walkers
    n = int(rng.integers(lo_n, hi_n + 1))
    for j in range(n):
        walker = make_walker(
            rng,
            n_static + j,
            floor_y,
            half_fov,
            z_range=preset.walker_z,
            speed_range=preset.speed,
            max_sway=0.2,
            pace_m=preset.pace_m,
            in_view_at=duration * (j + 0.5) / n if preset.in_view else None,
        )
        things.append(walker)
    return preset_motion(preset, rng), (0.0, 0.0)
