"""TUM-style RGB-D sequences: a static room and objects, 1-3 walking people, a moving camera.

The world is layered: a textured back wall and floor (``camera.Room``) and upright,
camera-facing object sprites standing on the floor. A pinhole camera moves slowly in x/y/z
and yaw, so static objects move on screen by amounts that depend on their depth (parallax).
Walkers cross the room articulating a side-view gait. Every frame also gets its ground-truth
dynamic mask and its true static background (the same frame rendered without the walkers).

Layout of one sequence folder::

    rgb/<t>.png  depth/<t+0.005>.png  rgb.txt  depth.txt  groundtruth.txt  camera.yaml
    dynamic/<t>.png                       uint8, 255 = visible pixel of a moving object
    background/rgb/<t>.png  background/depth/<t+0.005>.png   static scene of the same frame
    annotations.json                      COCO, one image per frame (+ track_id, moving)

``background/depth`` and ``depth`` share the depth frame's timestamp; ``dynamic`` and
``background/rgb`` share the colour frame's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from slimseg.data.synth.camera import Intrinsics, Pose, Room, project, render_room
from slimseg.data.synth.categories import BY_NAME, CATEGORIES
from slimseg.data.synth.coco_writer import CocoBuilder, frame_annotations
from slimseg.data.synth.presets import PRESETS, preset_motion
from slimseg.data.synth.scene import (
    DEPTH_SCALE,
    STREAM_SEQUENCE,
    Frame,
    Placement,
    Sensor,
    compose,
    finish_depth,
    finish_rgb,
    frame_rng,
    make_room,
    sample_noise,
)
from slimseg.data.synth.shapes import Style, sample_style, walking_pose
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import write_png, write_text, write_yaml

FPS = 30.0
T0_US = 1_305_031_102_175_304  # first colour timestamp (microseconds), a TUM-like epoch
DEPTH_OFFSET_US = 5_000  # depth frames are stamped 5 ms after colour: exercises association
STREAM_SEQUENCE_NOISE = STREAM_SEQUENCE + 1
STREAM_SEQUENCE_PRESET = STREAM_SEQUENCE + 2


def timestamp(frame: int, offset_us: int = 0) -> str:
    """TUM timestamp string (seconds, 6 decimals) of ``frame`` at 30 Hz, exact in integers."""
    us = T0_US + round(frame * 1_000_000 / FPS) + offset_us
    return f"{us // 1_000_000}.{us % 1_000_000:06d}"


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

    def pose(self, i: int) -> Pose:
        """Camera-to-world pose of frame ``i``."""
        return camera_pose(self.motion, self.drift, i / FPS)


def camera_pose(
    motion: dict[str, tuple[float, float, float]], drift: tuple[float, float], t: float
) -> Pose:
    """Smooth camera path: a sinusoid per axis (``x, y, z, yaw``) plus a slow x/z drift."""
    val = {a: amp * np.sin(2 * np.pi * f * t + ph) for a, (amp, f, ph) in motion.items()}
    return Pose(
        x=float(val["x"] + drift[0] * t),
        y=float(val["y"]),
        z=float(val["z"] + drift[1] * t),
        yaw=float(val["yaw"]),
    )


def build_world(
    seed: int,
    index: int,
    frames: int,
    width: int = 640,
    height: int = 480,
    preset: str | None = None,
) -> World:
    """Random room, 3-6 static objects (sometimes a standing person), 1-3 walkers, camera path.

    Deterministic in ``(seed, index, preset)``; ``frames`` only bounds the camera path.
    ``preset`` (a :data:`~slimseg.data.synth.presets.PRESETS` name) replaces the camera path
    and the walkers; None keeps the default sequences byte for byte.
    """
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
    for j in range(int(rng.integers(1, 4))):
        z = float(rng.uniform(1.9, min(3.6, wall_z - 0.8)))
        speed = float(rng.uniform(0.5, 1.2))
        span = 2 * (z * half_fov + 0.5)  # from just outside the left edge to outside the right
        # in the central part of the view, heading either way, halfway through the sequence
        s_mid = span * (rng.uniform(0.25, 0.75) + float(rng.integers(2)))
        style = sample_style("person", rng).with_params(tilt=float(rng.normal(0, 0.03)))
        lo, hi = BY_NAME["person"].height_m
        things.append(
            Thing(
                style,
                x=0.0,
                z=z,
                bottom=floor_y,
                height=float(rng.uniform(lo, hi)),
                track_id=n_static + j,
                moving=True,
                speed=speed,
                span=span,
                offset=(s_mid - speed * duration / 2) % (2 * span),
                sway=float(rng.uniform(0.0, 0.3)),
                cadence=speed / float(rng.uniform(1.1, 1.5)),
                phase=float(rng.uniform(0, 2 * np.pi)),
                amplitude=float(rng.uniform(0.35, 0.5)),
            )
        )
    if preset is not None:
        motion, drift = _apply_preset(preset, seed, index, things, n_static, floor_y, half_fov)
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
) -> tuple[dict[str, tuple[float, float, float]], tuple[float, float]]:
    """Replace the walkers in ``things`` (in place) and return the preset's camera path."""
    if name not in PRESETS:
        raise SlimsegError(f"unknown sequence preset {name!r}; valid: {sorted(PRESETS)}")
    preset = PRESETS[name]
    rng = frame_rng(seed, index, STREAM_SEQUENCE_PRESET)
    del things[n_static:]
    lo_n, hi_n = preset.walkers
    for j in range(int(rng.integers(lo_n, hi_n + 1))):
        z = float(rng.uniform(*preset.walker_z))
        speed = float(rng.uniform(*preset.speed))
        if preset.pace_m is None:  # cross the whole view, as the default walkers do
            x, span = 0.0, 2 * (z * half_fov + 0.5)
        else:  # shift in place around a spot in the central part of the view
            x, span = float(z * half_fov * rng.uniform(-0.5, 0.5)), preset.pace_m
        style = sample_style("person", rng).with_params(tilt=float(rng.normal(0, 0.03)))
        lo, hi = BY_NAME["person"].height_m
        things.append(
            Thing(
                style,
                x=x,
                z=z,
                bottom=floor_y,
                height=float(rng.uniform(lo, hi)),
                track_id=n_static + j,
                moving=True,
                speed=speed,
                span=span,
                offset=float(rng.uniform(0, 2 * span)),
                sway=float(rng.uniform(0.0, 0.2)),
                cadence=speed / float(rng.uniform(1.1, 1.5)),
                phase=float(rng.uniform(0, 2 * np.pi)),
                amplitude=float(rng.uniform(0.35, 0.5)),
            )
        )
    return preset_motion(preset, rng), (0.0, 0.0)


@dataclass
class SequenceFrame:
    """One rendered sequence frame.

    ``frame``: the observed frame (``rgb``, ``depth`` uint16, ``labels``, ``placements``).
    ``background_rgb`` ``uint8 [H, W, 3]`` / ``background_depth`` ``uint16 [H, W]``: the same
    frame without moving objects (identical to ``frame`` outside ``dynamic``). ``dynamic``
    ``uint8 [H, W]``: 255 on visible pixels of moving objects. ``pose``: camera-to-world.
    """

    frame: Frame
    background_rgb: np.ndarray
    background_depth: np.ndarray
    dynamic: np.ndarray
    pose: Pose


def placements_at(world: World, pose: Pose, t: float) -> list[Placement]:
    """Project every thing into the camera at ``pose`` (things behind the camera are left out)."""
    out = []
    k = world.k
    for th in world.things:
        style, bottom = th.at(t)
        top = bottom - (0.0, th.height, 0.0)
        uv, z = project(k, pose, np.stack([bottom, top]))
        if z[0] < 0.3:
            continue
        size = float(uv[0, 1] - uv[1, 1])
        cx, cy = float(uv[0, 0]), float((uv[0, 1] + uv[1, 1]) / 2)
        out.append(Placement(style, cx, cy, size, float(z[0]), th.track_id, th.moving))
    return out


def render_sequence_frame(world: World, i: int) -> SequenceFrame:
    """Render frame ``i`` of ``world`` with its dynamic mask and static background."""
    pose = world.pose(i)
    k = world.k
    room_rgb, room_depth = render_room(k, pose, world.room)
    placements = placements_at(world, pose, i / FPS)
    rgb, depth_m, labels = compose(room_rgb, room_depth, placements)
    static = [p for p in placements if not p.moving]
    bg_rgb, bg_depth_m, _ = compose(room_rgb, room_depth, static)
    moving_ids = [j + 1 for j, p in enumerate(placements) if p.moving]
    dynamic = np.isin(labels, moving_ids)

    nrng = np.random.default_rng([STREAM_SEQUENCE_NOISE, world.seed * 1_000_003 + world.index, i])
    noise = sample_noise(nrng, world.sensor, k.height, k.width)
    bg_out = finish_rgb(bg_rgb, world.sensor, noise)
    rgb_out = np.where(dynamic[..., None], finish_rgb(rgb, world.sensor, noise), bg_out)
    frame = Frame(
        rgb=rgb_out,
        depth=finish_depth(depth_m, world.sensor, noise),
        labels=labels,
        placements=placements,
        depth_m=depth_m,
        room_depth_m=room_depth,
    )
    return SequenceFrame(
        frame=frame,
        background_rgb=bg_out,
        background_depth=finish_depth(bg_depth_m, world.sensor, noise),
        dynamic=dynamic.astype(np.uint8) * 255,
        pose=pose,
    )


_HEADERS = {
    "rgb": "# color images\n# file: '{name}'\n# timestamp filename\n",
    "depth": "# depth maps\n# file: '{name}'\n# timestamp filename\n",
    "gt": "# ground truth trajectory\n# file: '{name}'\n# timestamp tx ty tz qx qy qz qw\n",
}


def write_sequence(
    folder: Path,
    seed: int,
    index: int,
    frames: int,
    size: tuple[int, int] = (640, 480),
    on_frame: Callable[[], None] | None = None,
    preset: str | None = None,
) -> dict[str, int]:
    """Render and write sequence ``index`` into ``folder`` (TUM layout, see module doc).

    Returns counts: ``frames``, ``instances`` and per-category annotation counts.
    ``on_frame`` is called after each frame (progress bars). ``preset``: see
    :mod:`slimseg.data.synth.presets` (None: the default sequences).
    """
    world = build_world(seed, index, frames, *size, preset=preset)
    k = world.k
    for sub in ("rgb", "depth", "dynamic", "background/rgb", "background/depth"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    name = f"slimseg_synth_{preset or 'seq'}_{index:03d}"
    coco = CocoBuilder(f"slimseg synthetic RGB-D sequence {index} (seed {seed})")
    rgb_lines, depth_lines, gt_lines = [], [], []
    counts: dict[str, int] = {"frames": frames}
    for i in range(frames):
        sf = render_sequence_frame(world, i)
        ts, tsd = timestamp(i), timestamp(i, DEPTH_OFFSET_US)
        write_png(folder / "rgb" / f"{ts}.png", sf.frame.rgb)
        write_png(folder / "depth" / f"{tsd}.png", sf.frame.depth)
        write_png(folder / "dynamic" / f"{ts}.png", sf.dynamic)
        write_png(folder / "background" / "rgb" / f"{ts}.png", sf.background_rgb)
        write_png(folder / "background" / "depth" / f"{tsd}.png", sf.background_depth)
        rgb_lines.append(f"{ts} rgb/{ts}.png\n")
        depth_lines.append(f"{tsd} depth/{tsd}.png\n")
        p, q = sf.pose, sf.pose.quaternion()
        vals = (p.x, p.y, p.z, *q)
        gt_lines.append(ts + "".join(f" {v:.6f}" for v in vals) + "\n")
        image = {
            "id": i + 1,
            "file_name": f"rgb/{ts}.png",
            "width": k.width,
            "height": k.height,
            "timestamp": float(ts),
            "depth_file": f"depth/{tsd}.png",
        }
        anns = frame_annotations(sf.frame, i + 1, extra=True)
        coco.add(image, anns)
        for a in anns:
            cat = CATEGORIES[a["category_id"] - 1].name
            counts[cat] = counts.get(cat, 0) + 1
        if on_frame is not None:
            on_frame()
    write_text(folder / "rgb.txt", _HEADERS["rgb"].format(name=name) + "".join(rgb_lines))
    write_text(folder / "depth.txt", _HEADERS["depth"].format(name=name) + "".join(depth_lines))
    write_text(folder / "groundtruth.txt", _HEADERS["gt"].format(name=name) + "".join(gt_lines))
    write_yaml(
        folder / "camera.yaml",
        {
            "width": k.width,
            "height": k.height,
            "fx": k.fx,
            "fy": k.fy,
            "cx": k.cx,
            "cy": k.cy,
            "distortion": [0.0, 0.0, 0.0, 0.0, 0.0],
            "fps": FPS,
            "depth_scale": DEPTH_SCALE,
            "depth_offset_s": DEPTH_OFFSET_US / 1e6,
        },
    )
    coco.write(folder / "annotations.json")
    counts["instances"] = len(coco.annotations)
    return counts
