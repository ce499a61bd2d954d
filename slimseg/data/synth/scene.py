"""Compose one frame: room background, instances layered far to near, depth, sensor effects.

``render_image`` is the image-mode generator: a random room seen by a random camera, 1-8
instances at random places, scales (5x range) and depths, then colour/blur/noise and depth
noise/holes. Instances are painted far -> near into a label map, so each instance's mask is
exactly its visible part and depth is consistent with the occlusion order.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from slimseg.data.synth.camera import Intrinsics, Pose, Room, Surface, render_room, surface_window
from slimseg.data.synth.categories import BY_NAME, CATEGORIES
from slimseg.data.synth.shapes import draw, sample_style
from slimseg.data.synth.style import Style
from slimseg.data.synth.texture import make_texture

DEPTH_SCALE = 5000.0  # TUM: uint16 depth / 5000 = metres; 0 = invalid
FOCAL_BASELINE = 40.0  # depth-sensor focal length (px) x baseline (m), Kinect-like
MAX_INSTANCES = 8
STREAM_TRAIN, STREAM_VAL, STREAM_SEQUENCE = 0, 1, 2


def frame_rng(seed: int, index: int, stream: int = STREAM_TRAIN) -> np.random.Generator:
    """The generator of one image: seeded with ``(stream, seed * 1_000_003 + index)``.

    Independent of every other image, so frames can be rendered in any order or in parallel;
    ``stream`` separates train, val and sequence frames of the same ``seed`` and ``index``.
    """
    return np.random.default_rng([int(stream), int(seed) * 1_000_003 + int(index)])


@dataclass
class Placement:
    """One instance in one frame: its look, centre ``(cx, cy)`` and height ``size`` in
    pixels, and its ``depth`` in metres (flat: every pixel of the instance has this depth)."""

    style: Style
    cx: float
    cy: float
    size: float
    depth: float
    track_id: int = -1
    moving: bool = False

    @property
    def category_id(self) -> int:
        """1-based COCO category id."""
        return BY_NAME[self.style.category].id


@dataclass
class Frame:
    """A rendered frame.

    ``rgb`` ``uint8 [H, W, 3]`` (RGB, sensor effects applied); ``depth`` ``uint16 [H, W]``
    (TUM scale 5000, 0 = invalid); ``labels`` ``int16 [H, W]`` (0 = background, ``i + 1`` =
    visible pixel of ``placements[i]``); ``depth_m`` ``float32 [H, W]`` clean composed depth in
    metres; ``room_depth_m`` ``float32 [H, W]`` clean depth of the room alone.
    """

    rgb: np.ndarray
    depth: np.ndarray
    labels: np.ndarray
    placements: list[Placement]
    depth_m: np.ndarray
    room_depth_m: np.ndarray
    meta: dict = field(default_factory=dict)

    def mask(self, i: int) -> np.ndarray:
        """Visible mask of ``placements[i]``: ``bool [H, W]``."""
        return self.labels == i + 1


def compose(
    rgb: np.ndarray, depth: np.ndarray, placements: list[Placement]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paint ``placements`` far -> near over ``rgb`` (``uint8 [H, W, 3]``) and ``depth``
    (``float32 [H, W]`` m). Returns new ``rgb``, ``depth`` and ``labels`` (``int16 [H, W]``,
    ``i + 1`` where ``placements[i]`` is visible). Equal depths keep list order (later on top).
    """
    rgb, depth = rgb.copy(), depth.copy()
    h, w = depth.shape
    labels = np.zeros((h, w), np.int16)
    order = sorted(range(len(placements)), key=lambda i: -placements[i].depth)
    for i in order:
        p = placements[i]
        patch = draw(p.style, p.cx, p.cy, p.size, w, h)
        if patch is None:
            continue
        ph, pw = patch.mask.shape
        sl = (slice(patch.y0, patch.y0 + ph), slice(patch.x0, patch.x0 + pw))
        m = patch.mask > 0
        rgb[sl][m] = patch.rgb[m]
        depth[sl][m] = p.depth
        labels[sl][m] = i + 1
    return rgb, depth, labels


# -- sensor effects ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Sensor:
    """Photometric and depth-sensor effects of one frame (or one whole sequence)."""

    gain: tuple[float, float, float] = (1.0, 1.0, 1.0)
    bias: float = 0.0
    gamma: float = 1.0
    blur: float = 0.0
    noise: float = 0.0
    depth_noise: float = 0.4  # disparity noise sigma, in 1/8-pixel steps (Kinect-like)
    holes: int = 0


def sample_sensor(rng: np.random.Generator, strength: float = 1.0) -> Sensor:
    """Random colour cast, brightness, gamma, blur sigma (px), pixel noise and depth holes."""
    return Sensor(
        gain=tuple(float(g) for g in rng.uniform(0.75, 1.25) * rng.uniform(0.9, 1.1, 3)),
        bias=float(rng.uniform(-20, 20) * strength),
        gamma=float(np.exp(rng.uniform(-0.25, 0.25) * strength)),
        blur=float(rng.choice([0.0, rng.uniform(0.4, 1.3)]) * strength),
        noise=float(rng.uniform(0.0, 5.0) * strength),
        depth_noise=float(rng.uniform(0.15, 0.6)),
        holes=int(rng.integers(0, 4)),
    )


@dataclass
class SensorNoise:
    """Random fields of one frame, kept apart so the same noise can be applied to two
    renders (a frame and its static background): ``rgb`` ``float32 [H, W, 3]`` unit normal,
    ``depth`` ``float32 [H, W]`` unit normal, ``holes`` ``bool [H, W]`` invalid depth."""

    rgb: np.ndarray
    depth: np.ndarray
    holes: np.ndarray


def sample_noise(rng: np.random.Generator, sensor: Sensor, h: int, w: int) -> SensorNoise:
    """Noise fields and ``sensor.holes`` elliptic depth holes for an ``h x w`` frame."""
    holes = np.zeros((h, w), np.uint8)
    for _ in range(sensor.holes):
        c = (int(rng.integers(w)), int(rng.integers(h)))
        ax = (int(rng.uniform(0.01, 0.05) * w) + 1, int(rng.uniform(0.01, 0.05) * h) + 1)
        cv2.ellipse(holes, c, ax, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    return SensorNoise(
        rgb=rng.standard_normal((h, w, 3), dtype=np.float32),
        depth=rng.standard_normal((h, w), dtype=np.float32),
        holes=holes > 0,
    )


def _tone(x: np.ndarray, sensor: Sensor) -> np.ndarray:
    """Colour cast and gamma of ``float32 [..., 3]`` values in 0-255 (same shape out)."""
    x = np.clip(x * np.asarray(sensor.gain, np.float32) + sensor.bias, 0, 255)
    if abs(sensor.gamma - 1.0) > 1e-3:
        # float64: numpy's float32 power is libm's powf, but SVML's on AVX-512 CPUs; the two
        # differ by an ulp, enough to flip a value at a .5 rounding boundary by one level.
        x = (255.0 * (x.astype(np.float64) / 255.0) ** sensor.gamma).astype(np.float32)
    return x


def finish_rgb(rgb: np.ndarray, sensor: Sensor, noise: SensorNoise) -> np.ndarray:
    """Apply colour cast, gamma, blur and noise: ``uint8 [H, W, 3]`` (or ``float32``, 0-255,
    as motion blur gives) -> ``uint8 [H, W, 3]``."""
    if rgb.dtype == np.uint8:  # 256 levels per channel: tone each once, then look them up
        x = _tone(np.arange(256, dtype=np.float32)[:, None], sensor)[rgb, np.arange(3)]
    else:
        x = _tone(rgb.astype(np.float32), sensor)
    if sensor.blur > 0.3:
        x = cv2.GaussianBlur(x, (0, 0), sensor.blur)
    if sensor.noise > 0:
        x = x + noise.rgb * sensor.noise
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def finish_depth(depth_m: np.ndarray, sensor: Sensor, noise: SensorNoise) -> np.ndarray:
    """Structured-light depth: ``float32 [H, W]`` metres -> ``uint16 [H, W]`` TUM depth.

    Depth becomes a disparity ``8 * FOCAL_BASELINE / z`` in 1/8-pixel steps, gets Gaussian
    noise (``sensor.depth_noise`` steps), is rounded to whole steps and converted back, so the
    error grows like ``z^2`` (about 3 mm at 1 m, 7 cm at 5 m) as with a Kinect. Then
    ``round(z * 5000)``; 0 marks holes (invalid).
    """
    disp = (8.0 * FOCAL_BASELINE) / np.maximum(depth_m, 1e-3)
    disp = np.maximum(np.rint(disp + noise.depth * sensor.depth_noise), 1.0)
    z = (8.0 * FOCAL_BASELINE) / disp
    d = np.clip(np.rint(z * DEPTH_SCALE), 1, 65535).astype(np.uint16)
    d[noise.holes | ~np.isfinite(depth_m)] = 0
    return d


# -- room ------------------------------------------------------------------------------------
_MAX_TEXTURE_PX = 6_000_000


def _surface(
    rng: np.random.Generator,
    box: tuple[float, float, float, float],
    px_per_m: float,
    kind: str,
    clutter: float,
) -> Surface:
    u0, u1, v0, v1 = box
    area = (u1 - u0) * (v1 - v0)
    px_per_m = min(px_per_m, float(np.sqrt(_MAX_TEXTURE_PX / max(area, 1e-6))))
    w = max(int(np.ceil((u1 - u0) * px_per_m)), 2)
    h = max(int(np.ceil((v1 - v0) * px_per_m)), 2)
    return Surface(make_texture(rng, w, h, px_per_m, kind, clutter), u0, v0, px_per_m)


def make_room(
    rng: np.random.Generator,
    k: Intrinsics,
    poses: list[Pose],
    wall_z: float,
    floor_y: float | None,
    clutter: float = 1.0,
) -> Room:
    """Textured wall and floor covering everything ``poses`` see, at about one texture pixel
    per image pixel at the nearest visible point."""
    wall_box, floor_box = surface_window(k, poses, wall_z, floor_y)
    wall = _surface(rng, wall_box, k.fx / wall_z * 1.2, "wall", clutter)
    floor = None
    if floor_box is not None and floor_y is not None:
        near = max(floor_box[2], 0.5)
        floor = _surface(rng, floor_box, k.fx / near, "floor", clutter)
    return Room(wall_z, floor_y, wall, floor)


# -- image mode --------------------------------------------------------------------------------
_CAT_NAMES = [c.name for c in CATEGORIES]
_CAT_P = np.array([c.weight for c in CATEGORIES]) / sum(c.weight for c in CATEGORIES)
MIN_SCALE, MAX_SCALE = 0.1, 0.5  # instance height as a fraction of the image size (5x range)
NEAR_M, FAR_M = 0.6, 2.8  # instance depths; the room is always farther than FAR_M
ROOM_MIN_M = 3.0


def sample_placements(rng: np.random.Generator, imgsz: int) -> list[Placement]:
    """1-8 random instances for a square ``imgsz`` image; bigger ones tend to be nearer."""
    out: list[Placement] = []
    for _ in range(int(rng.integers(1, MAX_INSTANCES + 1))):
        name = _CAT_NAMES[int(rng.choice(len(_CAT_NAMES), p=_CAT_P))]
        t = rng.random()  # log-uniform scale in [MIN_SCALE, MAX_SCALE]
        size = imgsz * MIN_SCALE * (MAX_SCALE / MIN_SCALE) ** t
        depth = float(np.clip(2.65 - 1.9 * t + rng.uniform(-0.15, 0.15), NEAR_M, FAR_M))
        if out and rng.random() < 0.4:  # next to an earlier one: frequent partial occlusion
            ref = out[int(rng.integers(len(out)))]
            cx = ref.cx + rng.normal(0.0, 0.35) * ref.size
            cy = ref.cy + rng.normal(0.0, 0.35) * ref.size
        else:
            cx, cy = rng.uniform(0.03, 0.97, 2) * imgsz
        out.append(Placement(sample_style(name, rng), float(cx), float(cy), float(size), depth))
    return out


def render_image(seed: int, index: int, imgsz: int, stream: int = STREAM_TRAIN) -> Frame:
    """Render image ``index`` of an image-mode split (square ``imgsz``), deterministic in
    ``(seed, index, stream)``."""
    rng = frame_rng(seed, index, stream)
    k = Intrinsics.from_fov(imgsz, imgsz, rng.uniform(50.0, 70.0))
    pose = Pose(yaw=float(rng.uniform(-0.25, 0.25)))
    wall_z = float(rng.uniform(3.6, 5.5))
    floor_y = None
    if rng.random() < 0.75:  # floor whose nearest visible point is at least ROOM_MIN_M away
        yn_max = (imgsz - 1 - k.cy) / k.fy
        floor_y = float(ROOM_MIN_M * 1.02 * yn_max * rng.uniform(1.0, 1.3))
    room = make_room(rng, k, [pose], wall_z, floor_y)
    room_rgb, room_depth = render_room(k, pose, room)
    placements = sample_placements(rng, imgsz)
    rgb, depth_m, labels = compose(room_rgb, room_depth, placements)
    sensor = sample_sensor(rng)
    noise = sample_noise(rng, sensor, imgsz, imgsz)
    return Frame(
        rgb=finish_rgb(rgb, sensor, noise),
        depth=finish_depth(depth_m, sensor, noise),
        labels=labels,
        placements=placements,
        depth_m=depth_m,
        room_depth_m=room_depth,
    )
