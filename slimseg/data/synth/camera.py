"""Pinhole camera, planar camera poses and the room (back wall + floor) it looks at.

Frames: camera x right, y down, z forward (OpenCV/TUM). The world frame is the camera frame
of a reference pose; the camera translates in x/y/z and turns by ``yaw`` about the vertical
(y) axis. The room is a fronto-parallel wall at ``Z = wall_z`` and an optional floor at
``Y = floor_y`` (y down, so the floor is ``floor_y`` metres below the camera's reference
height). Depth is the camera-frame ``z`` of the surface hit, as in TUM depth images.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels for a ``width x height`` image."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float) -> Intrinsics:
        """Square pixels, principal point at the image centre, horizontal FOV in degrees."""
        f = width / (2.0 * np.tan(np.radians(hfov_deg) / 2.0))
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    @classmethod
    def tum(cls, width: int = 640, height: int = 480) -> Intrinsics:
        """The TUM RGB-D default (525 px focal at 640x480), scaled to ``width``."""
        f = 525.0 * width / 640.0
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)


@dataclass(frozen=True)
class Pose:
    """Camera-to-world pose: position ``(x, y, z)`` in metres and ``yaw`` (radians, about y)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    yaw: float = 0.0

    def rotation(self) -> np.ndarray:
        """``float64 [3, 3]`` camera-to-world rotation."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])

    def quaternion(self) -> tuple[float, float, float, float]:
        """``(qx, qy, qz, qw)`` of :meth:`rotation` (TUM order)."""
        return (0.0, float(np.sin(self.yaw / 2)), 0.0, float(np.cos(self.yaw / 2)))

    def position(self) -> np.ndarray:
        """``float64 [3]`` camera centre in the world."""
        return np.array([self.x, self.y, self.z])


@lru_cache(maxsize=8)
def _normalized_grid(k: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    xn = (np.arange(k.width, dtype=np.float32) - k.cx) / k.fx
    yn = (np.arange(k.height, dtype=np.float32) - k.cy) / k.fy
    xs, ys = np.meshgrid(xn, yn)
    xs.setflags(write=False)
    ys.setflags(write=False)
    return xs, ys


def border_rays(k: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Normalized ray coordinates ``(xn, yn)`` (``float32 [N]``) of the image border pixels."""
    xs, ys = _normalized_grid(k)
    sel = np.zeros(xs.shape, bool)
    sel[0, :] = sel[-1, :] = sel[:, 0] = sel[:, -1] = True
    return xs[sel], ys[sel]


def project(k: Intrinsics, pose: Pose, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points ``float [N, 3]`` -> pixels ``float64 [N, 2]`` and camera depth ``[N]``."""
    pc = (np.asarray(points, np.float64) - pose.position()) @ pose.rotation()
    z = pc[:, 2]
    zs = np.where(np.abs(z) > 1e-9, z, 1e-9)
    uv = np.stack([k.fx * pc[:, 0] / zs + k.cx, k.fy * pc[:, 1] / zs + k.cy], 1)
    return uv, z


@dataclass(frozen=True)
class RoomHits:
    """Per-ray surface hits: ``depth`` (camera z, m), ``floor`` (bool, hit is on the floor),
    ``u, v`` world surface coordinates (wall: X, Y; floor: X, Z). All ``[...]`` like the rays."""

    depth: np.ndarray
    floor: np.ndarray
    u: np.ndarray
    v: np.ndarray


def room_hits(
    pose: Pose, xn: np.ndarray, yn: np.ndarray, wall_z: float, floor_y: float | None
) -> RoomHits:
    """Intersect camera rays ``(xn, yn, 1)`` with the wall and floor planes."""
    c, s = np.cos(pose.yaw), np.sin(pose.yaw)
    dx = (c * xn + s).astype(np.float32)
    dz = (c - s * xn).astype(np.float32)
    t_wall = (wall_z - pose.z) / np.maximum(dz, 1e-3)
    if floor_y is None:
        t_floor = np.full_like(t_wall, np.inf)
    else:
        t_floor = np.where(yn > 1e-4, (floor_y - pose.y) / np.maximum(yn, 1e-4), np.inf)
    floor = t_floor < t_wall
    t = np.where(floor, t_floor, t_wall).astype(np.float32)
    u = pose.x + t * dx
    v = np.where(floor, pose.z + t * dz, pose.y + t * yn)
    return RoomHits(t, floor, u.astype(np.float32), v.astype(np.float32))


@dataclass
class Surface:
    """A texture ``uint8 [h, w, 3]`` pinned to a world rectangle starting at ``(u0, v0)``.

    Texture pixel ``(col, row) = ((u - u0) * px_per_m, (v - v0) * px_per_m)``; for the floor
    ``v`` is world Z and rows run from near (``v0``) to far.
    """

    texture: np.ndarray
    u0: float
    v0: float
    px_per_m: float


@dataclass
class Room:
    """Back wall at ``Z = wall_z``, optional floor at ``Y = floor_y``, and their textures."""

    wall_z: float
    floor_y: float | None
    wall: Surface
    floor: Surface | None


def surface_window(
    k: Intrinsics, poses: list[Pose], wall_z: float, floor_y: float | None, margin: float = 0.3
) -> tuple[tuple[float, float, float, float], tuple[float, float, float, float] | None]:
    """World rectangles ``(u_min, u_max, v_min, v_max)`` of wall and floor seen by ``poses``."""
    xn, yn = border_rays(k)
    wall, floor = [], []
    for pose in poses:
        hits = room_hits(pose, xn, yn, wall_z, floor_y)
        for sel, out in ((~hits.floor, wall), (hits.floor, floor)):
            if sel.any():
                out.append((hits.u[sel].min(), hits.u[sel].max()))
                out.append((hits.v[sel].min(), hits.v[sel].max()))

    def box(vals: list[tuple[float, float]]) -> tuple[float, float, float, float]:
        us, vs = np.array(vals[0::2]), np.array(vals[1::2])
        return (
            float(us[:, 0].min()) - margin,
            float(us[:, 1].max()) + margin,
            float(vs[:, 0].min()) - margin,
            float(vs[:, 1].max()) + margin,
        )

    # The wall is always hit somewhere above the horizon; the floor only if visible.
    wall_box = box(wall) if wall else (-1.0, 1.0, -1.0, 1.0)
    return wall_box, (box(floor) if floor else None)


def render_room(k: Intrinsics, pose: Pose, room: Room) -> tuple[np.ndarray, np.ndarray]:
    """Room seen from ``pose``: RGB ``uint8 [H, W, 3]`` and depth ``float32 [H, W]`` metres."""
    xs, ys = _normalized_grid(k)
    hits = room_hits(pose, xs, ys, room.wall_z, room.floor_y)
    rgb = _sample(room.wall, hits.u, hits.v)
    if room.floor is not None and hits.floor.any():
        floor_rgb = _sample(room.floor, hits.u, hits.v)
        rgb = np.where(hits.floor[..., None], floor_rgb, rgb)
    return rgb, hits.depth


def _sample(surface: Surface, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    mx = (u - surface.u0) * surface.px_per_m
    my = (v - surface.v0) * surface.px_per_m
    return cv2.remap(
        surface.texture,
        mx.astype(np.float32),
        my.astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REFLECT_101,
    )
