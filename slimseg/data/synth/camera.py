"""Pinhole camera, planar camera poses and the room (back wall + floor) it looks at.

Frames: camera x right, y down, z forward (OpenCV/TUM). The world frame is the camera frame
of a reference pose; the camera translates in x/y/z and turns by ``yaw`` about the vertical
(y) axis, then (only the ``walking_rpy`` preset) by ``pitch`` about its own x axis and
``roll`` about its own optical (z) axis. The room is a fronto-parallel wall at
``Z = wall_z`` and an optional floor at ``Y = floor_y`` (y down, so the floor is ``floor_y``
metres below the camera's reference height). Depth is the camera-frame ``z`` of the surface
hit, as in TUM depth images.
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
    """Camera-to-world pose: position ``(x, y, z)`` in metres and rotation
    ``R = R_y(yaw) R_x(pitch) R_z(roll)`` (radians; right-handed rotations about the world's
    vertical y axis, then the camera's own x axis, then its optical z axis; positive pitch
    tilts the view up, towards -y). With ``pitch = roll = 0`` (every pose but the
    ``walking_rpy`` preset's) the yaw-only formulas below are used, keeping their bytes."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    yaw: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0

    @property
    def yaw_only(self) -> bool:
        """True when the pose turns about the vertical axis only."""
        return self.pitch == 0.0 and self.roll == 0.0

    def rotation(self) -> np.ndarray:
        """``float64 [3, 3]`` camera-to-world rotation."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        ry = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        if self.yaw_only:
            return ry
        c, s = np.cos(self.pitch), np.sin(self.pitch)
        rx = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
        c, s = np.cos(self.roll), np.sin(self.roll)
        rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return ry @ rx @ rz

    def quaternion(self) -> tuple[float, float, float, float]:
        """``(qx, qy, qz, qw)`` of :meth:`rotation` (TUM order)."""
        if self.yaw_only:
            return (0.0, float(np.sin(self.yaw / 2)), 0.0, float(np.cos(self.yaw / 2)))
        q = _axis_quat(1, self.yaw)
        q = _quat_mul(q, _axis_quat(0, self.pitch))
        q = _quat_mul(q, _axis_quat(2, self.roll))
        return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))

    def position(self) -> np.ndarray:
        """``float64 [3]`` camera centre in the world."""
        return np.array([self.x, self.y, self.z])


def _axis_quat(axis: int, angle: float) -> np.ndarray:
    """``float64 [4]`` ``(qx, qy, qz, qw)`` of a rotation by ``angle`` about axis 0/1/2."""
    q = np.zeros(4)
    q[axis], q[3] = np.sin(angle / 2), np.cos(angle / 2)
    return q


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a b`` of ``(x, y, z, w)`` quaternions (rotation ``a`` after ``b``)."""
    av, aw, bv, bw = a[:3], a[3], b[:3], b[3]
    v = aw * bv + bw * av + np.cross(av, bv)
    return np.array([*v, aw * bw - av @ bv])


@lru_cache(maxsize=8)
def _normalized_grid(k: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Read-only ``float32 [H, W]`` normalized ray coordinates ``(xn, yn)`` of every pixel."""
    xn = (np.arange(k.width, dtype=np.float32) - k.cx) / k.fx
    yn = (np.arange(k.height, dtype=np.float32) - k.cy) / k.fy
    xs, ys = np.meshgrid(xn, yn)
    xs.setflags(write=False)
    ys.setflags(write=False)
    return xs, ys


def normalized_grid(k: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Normalized ray coordinates ``(xn, yn)`` of every pixel, ``float32 [H, W]`` each
    (cached, read-only)."""
    return _normalized_grid(k)


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
    if pose.yaw_only:
        c, s = np.cos(pose.yaw), np.sin(pose.yaw)
        dx = (c * xn + s).astype(np.float32)
        dy = yn
        dz = (c - s * xn).astype(np.float32)
    else:  # the ray's world direction R (xn, yn, 1)
        r = pose.rotation().astype(np.float32)
        dx, dy, dz = (r[j, 0] * xn + r[j, 1] * yn + r[j, 2] for j in range(3))
    t_wall = (wall_z - pose.z) / np.maximum(dz, 1e-3)
    if floor_y is None:
        t_floor = np.full_like(t_wall, np.inf)
    else:
        t_floor = np.where(dy > 1e-4, (floor_y - pose.y) / np.maximum(dy, 1e-4), np.inf)
    floor = t_floor < t_wall
    t = np.where(floor, t_floor, t_wall).astype(np.float32)
    u = pose.x + t * dx
    v = np.where(floor, pose.z + t * dz, pose.y + t * dy)
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
