"""TUM-style RGB-D sequences: a static room and objects, 1-3 walking people, a moving camera.

What a sequence shows (room, objects, walkers, camera path) is fixed by
:func:`~slimseg.data.synth.world.build_world`; this module renders its frames and writes them.
Every frame also gets its ground-truth dynamic mask and its true static background (the same
frame rendered without the walkers).

Layout of one sequence folder::

    rgb/<t>.png  depth/<t+0.005>.png  rgb.txt  depth.txt  groundtruth.txt  camera.yaml
    dynamic/<t>.png                       uint8, 255 = visible pixel of a moving object
    background/rgb/<t>.png  background/depth/<t+0.005>.png   static scene of the same frame
    annotations.json                      COCO, one image per frame (+ track_id, moving)

``background/depth`` and ``depth`` share the depth frame's timestamp; ``dynamic`` and
``background/rgb`` share the colour frame's.

With motion blur (``World.exposure`` > 0, :mod:`slimseg.data.synth.blur`) ``rgb`` and
``background/rgb`` are blurred over the exposure; ``depth``, ``background/depth``,
``dynamic`` and the annotations stay the sharp instant of the timestamp, and ``rgb`` equals
``background/rgb`` outside the walkers' blurred footprint (their sharp masks plus the streak
around them) rather than outside ``dynamic``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slimseg.data.synth.blur import WalkerLayer, blur_frame
from slimseg.data.synth.camera import Pose, project, render_room
from slimseg.data.synth.categories import CATEGORIES
from slimseg.data.synth.coco_writer import CocoBuilder, frame_annotations
from slimseg.data.synth.scene import (
    DEPTH_SCALE,
    STREAM_SEQUENCE,
    Frame,
    Placement,
    compose,
    finish_depth,
    finish_rgb,
    sample_noise,
)
from slimseg.data.synth.world import FPS, World, build_world
from slimseg.utils.atomic import write_png, write_text, write_yaml

T0_US = 1_305_031_102_175_304  # first colour timestamp (microseconds), a TUM-like epoch
DEPTH_OFFSET_US = 5_000  # depth frames are stamped 5 ms after colour: exercises association
STREAM_SEQUENCE_NOISE = STREAM_SEQUENCE + 1  # + 2: world.STREAM_SEQUENCE_PRESET


def timestamp(frame: int, offset_us: int = 0) -> str:
    """TUM timestamp string (seconds, 6 decimals) of ``frame`` at 30 Hz, exact in integers."""
    us = T0_US + round(frame * 1_000_000 / FPS) + offset_us
    return f"{us // 1_000_000}.{us % 1_000_000:06d}"


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
        dx, dy = uv[0] - uv[1]  # image of the upright axis, top -> bottom
        size = float(np.hypot(dx, dy))
        cx, cy = float((uv[0, 0] + uv[1, 0]) / 2), float((uv[0, 1] + uv[1, 1]) / 2)
        if dx != 0.0:  # a rolled camera: the sprite turns with the vertical (never for yaw only)
            style = style.with_params(tilt=style.params.get("tilt", 0.0) + np.arctan2(-dx, dy))
        out.append(Placement(style, cx, cy, size, float(z[0]), th.track_id, th.moving))
    return out


def render_sequence_frame(world: World, i: int, background: bool = True) -> SequenceFrame:
    """Render frame ``i`` of ``world`` with its dynamic mask and static background.

    ``background=False`` (training frames): the static background is composed only where
    motion blur needs it; otherwise ``background_rgb``/``background_depth`` are the frame's
    own (not the scene without walkers). ``frame`` is identical either way."""
    pose = world.pose(i)
    k = world.k
    room_rgb, room_depth = render_room(k, pose, world.room)
    placements = placements_at(world, pose, i / FPS)
    rgb, depth_m, labels = compose(room_rgb, room_depth, placements)
    if background or world.exposure > 0:
        static = [p for p in placements if not p.moving]
        bg_rgb, bg_depth_m, _ = compose(room_rgb, room_depth, static)
    else:
        bg_rgb, bg_depth_m = rgb, depth_m
    moving_ids = [j + 1 for j, p in enumerate(placements) if p.moving]
    dynamic = np.isin(labels, moving_ids)

    nrng = np.random.default_rng([STREAM_SEQUENCE_NOISE, world.seed * 1_000_003 + world.index, i])
    noise = sample_noise(nrng, world.sensor, k.height, k.width)
    changed = dynamic
    if world.exposure > 0:
        layers = _walker_layers(world, pose, i / FPS, labels, placements)
        poses = world.exposure_poses(i)
        bg_rgb, rgb, changed = blur_frame(k, poses, rgb, bg_rgb, bg_depth_m, layers)
    bg_out = finish_rgb(bg_rgb, world.sensor, noise)
    rgb_out = np.where(changed[..., None], finish_rgb(rgb, world.sensor, noise), bg_out)
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


def _walker_layers(
    world: World, pose: Pose, t: float, labels: np.ndarray, placements: list[Placement]
) -> list[WalkerLayer]:
    """The visible part of every moving placement as a :class:`WalkerLayer`, far to near; its
    own motion is that of its centre over the exposure, seen from the camera at ``pose``."""
    things = {th.track_id: th for th in world.things}
    out = []
    for j in sorted(range(len(placements)), key=lambda j: -placements[j].depth):
        p = placements[j]
        mask = labels == j + 1
        if not p.moving or not mask.any():
            continue
        th = things[p.track_id]
        ends = [th.at(t + d * world.exposure / 2)[1] - (0.0, th.height / 2, 0.0) for d in (-1, 1)]
        uv, _ = project(world.k, pose, np.stack(ends))
        out.append(
            WalkerLayer(mask, p.depth, (float(uv[1, 0] - uv[0, 0]), float(uv[1, 1] - uv[0, 1])))
        )
    return out


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
    exposure_ms: float | None = None,
    step: int = 1,
) -> dict[str, int]:
    """Render and write sequence ``index`` into ``folder`` (TUM layout, see module doc).

    Returns counts: ``frames`` (written), ``instances`` and per-category annotation counts.
    ``on_frame`` is called after each frame (progress bars). ``preset``: see
    :mod:`slimseg.data.synth.presets` (None: the default sequences); ``exposure_ms``: motion
    blur's shutter time (None: the preset's default, 0: no blur). ``step > 1`` writes
    training frames: every ``step``-th of the ``frames`` (true timestamps, so a 30 / step Hz
    sequence), without ``dynamic/`` and ``background/`` (nothing trains on them).
    """
    world = build_world(seed, index, frames, *size, preset=preset, exposure_ms=exposure_ms)
    k = world.k
    extras = step == 1
    subs = ("rgb", "depth", "dynamic", "background/rgb", "background/depth")
    for sub in subs if extras else subs[:2]:
        (folder / sub).mkdir(parents=True, exist_ok=True)
    name = f"slimseg_synth_{preset or 'seq'}_{index:03d}"
    coco = CocoBuilder(f"slimseg synthetic RGB-D sequence {index} (seed {seed})")
    rgb_lines, depth_lines, gt_lines = [], [], []
    kept = range(0, frames, step)
    counts: dict[str, int] = {"frames": len(kept)}
    for i in kept:
        sf = render_sequence_frame(world, i, background=extras)
        ts, tsd = timestamp(i), timestamp(i, DEPTH_OFFSET_US)
        write_png(folder / "rgb" / f"{ts}.png", sf.frame.rgb)
        write_png(folder / "depth" / f"{tsd}.png", sf.frame.depth)
        if extras:
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
