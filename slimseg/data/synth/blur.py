"""Motion blur of a finite exposure, for the synthetic sequences' RGB frames.

The shutter is open for ``World.exposure`` seconds centred on the frame's timestamp, and a
pixel integrates what passes over it meanwhile. The frame is blurred as layers, back to front:

- the static scene (room and static objects: the ``background/rgb`` render): each pixel's
  surface point (its depth, the frame's pose) is reprojected into the poses at the shutter's
  opening and closing; the image displacement between the two is the pixel's blur vector;
- the visible part of each walker, far to near: the displacement that the camera's motion
  gives a point at the walker's depth, plus the walker's own image motion over the exposure
  (that of its centre). Its colour and its coverage are blurred along that vector — the
  streak reaches outside the sharp mask, the background shows through at its edges — and
  composited over the layers behind it.

A layer is blurred by gathering: every pixel averages the sharp layer at ``n`` points evenly
spaced along its blur vector and centred on it (``cv2.remap``, bilinear), ``n`` = the longest
vector in pixels + 1 (at least 2), so the samples are at most 1 px apart: a box filter along
the motion, as a constant-velocity exposure gives. Not modelled: the limbs' swing within the
exposure, occlusions that change during it, and a static occluder in front of a walker (the
walker's streak passes over it). Depth and the ground-truth masks are never blurred: they are
the sharp instant of the timestamp.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from slimseg.data.synth.camera import Intrinsics, Pose, normalized_grid

MAX_SAMPLES = 64  # samples along the longest blur vector (64 px at most stays ≤ 1 px apart)
Window = tuple[int, int, int, int]  # x0, y0, x1, y1 (exclusive) in image pixels


@dataclass(frozen=True)
class WalkerLayer:
    """One walker in one frame: its visible pixels ``mask`` (``bool [H, W]``), its ``depth``
    (m, a flat sprite) and its own image motion ``shift`` ``(du, dv)`` px over the exposure."""

    mask: np.ndarray
    depth: float
    shift: tuple[float, float]


def reproject(
    k: Intrinsics, pose: Pose, depth: np.ndarray | float, other: Pose, window: Window | None = None
) -> np.ndarray:
    """Where the camera at ``other`` sees the surface points seen by the camera at ``pose``.

    ``depth``: ``float [h, w]`` (camera z, m) of the pixels of ``window`` (default: the whole
    ``H x W`` image), or one depth for all of them. Returns ``float32 [h, w, 2]`` pixel
    coordinates ``(u, v)`` in ``other``'s image.
    """
    x0, y0, x1, y1 = window or (0, 0, k.width, k.height)
    xn, yn = (g[y0:y1, x0:x1] for g in normalized_grid(k))
    rot = other.rotation().T @ pose.rotation()  # camera at pose -> camera at other
    m = rot.astype(np.float32)
    t = (other.rotation().T @ (pose.position() - other.position())).astype(np.float32)
    d = np.asarray(depth, np.float32)
    px, py, pz = (d * (m[j, 0] * xn + m[j, 1] * yn + m[j, 2]) + t[j] for j in range(3))
    pz = np.maximum(pz, 1e-3)
    return np.stack([k.fx * px / pz + k.cx, k.fy * py / pz + k.cy], axis=-1)


def displacement(
    k: Intrinsics,
    poses: tuple[Pose, Pose, Pose],
    depth: np.ndarray | float,
    window: Window | None = None,
) -> np.ndarray:
    """Blur vectors ``float32 [h, w, 2]`` (px) of the static surface at ``depth`` (as in
    :func:`reproject`) seen at ``poses = (opening, frame, closing)``: its image position at
    the shutter's closing minus that at its opening."""
    opening, pose, closing = poses
    return reproject(k, pose, depth, closing, window) - reproject(k, pose, depth, opening, window)


def line_blur(src: np.ndarray, flow: np.ndarray, border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
    """Average ``src`` (``float32 [h, w, C]``, C = 3 or 4) along each pixel's blur vector.

    ``flow``: ``float32 [h, w, 2]`` vectors (px) of the same pixels. Output pixel ``p`` is the
    mean of ``src`` sampled (bilinear, ``border`` outside) at ``p + s * flow[p]`` for ``n``
    values of ``s`` evenly spaced in ``[-1/2, 1/2]``. Returns ``float32 [h, w, C]``.
    """
    h, w = flow.shape[:2]
    longest = float(np.sqrt((flow**2).sum(-1).max())) if flow.size else 0.0
    n = int(min(max(2, np.ceil(longest) + 1), MAX_SAMPLES))
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    fx, fy = np.ascontiguousarray(flow[..., 0]), np.ascontiguousarray(flow[..., 1])
    acc = np.zeros(src.shape, np.float32)
    for j in range(n):
        s = np.float32((j + 0.5) / n - 0.5)
        acc += cv2.remap(src, gx + s * fx, gy + s * fy, cv2.INTER_LINEAR, borderMode=border)
    return acc / np.float32(n)


def blur_frame(
    k: Intrinsics,
    poses: tuple[Pose, Pose, Pose],
    rgb: np.ndarray,
    bg_rgb: np.ndarray,
    bg_depth: np.ndarray,
    layers: list[WalkerLayer],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Motion-blur one frame (see the module doc).

    ``poses``: the camera at the shutter's opening, at the frame's timestamp and at the
    closing; ``rgb`` ``uint8 [H, W, 3]``: the sharp frame (walkers' colours are read from it
    under their masks); ``bg_rgb`` ``uint8 [H, W, 3]`` and ``bg_depth`` ``float32 [H, W]`` (m):
    the sharp static scene; ``layers``: the walkers, far to near. Returns the blurred static
    scene and the blurred frame (``float32 [H, W, 3]``, 0-255) and the walkers' blurred
    footprint (``bool [H, W]``; the two images are equal outside it).
    """
    h, w = bg_depth.shape
    bg = line_blur(bg_rgb.astype(np.float32), displacement(k, poses, bg_depth))
    full = bg.copy()
    footprint = np.zeros((h, w), bool)
    for layer in layers:
        ys, xs = np.nonzero(layer.mask)
        if not len(ys):
            continue
        box = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
        shift = np.asarray(layer.shift, np.float32)
        reach = np.abs(displacement(k, poses, layer.depth, box) + shift).max()
        margin = int(np.ceil(0.6 * reach)) + 2  # the vectors only grow a little outside box
        x0, y0 = max(box[0] - margin, 0), max(box[1] - margin, 0)
        x1, y1 = min(box[2] + margin, w), min(box[3] + margin, h)
        flow = displacement(k, poses, layer.depth, (x0, y0, x1, y1)) + shift
        sl = (slice(y0, y1), slice(x0, x1))
        alpha = layer.mask[sl].astype(np.float32)[..., None]
        src = np.concatenate([rgb[sl].astype(np.float32) * alpha, alpha], axis=-1)
        out = line_blur(src, flow, cv2.BORDER_CONSTANT)
        cover = out[..., 3:]
        full[sl] = full[sl] * (1.0 - cover) + out[..., :3]
        footprint[sl] |= cover[..., 0] > 0
    return bg, full, footprint
