"""Procedural wall and floor textures with unannotated clutter (lines, blobs, posters, cables).

Textures live in world units: ``px_per_m`` texture pixels per metre, so patterns keep their
physical size whatever the image resolution, and a moving camera sees them with parallax.
Clutter is part of the background: it is never annotated and never occludes an instance.
"""

from __future__ import annotations

import colorsys

import cv2
import numpy as np

Color = tuple[int, int, int]


def _hsv(h: float, s: float, v: float) -> np.ndarray:
    return np.array(colorsys.hsv_to_rgb(h % 1.0, s, v), np.float32) * 255.0


def _rand_color(rng: np.random.Generator) -> tuple[int, int, int]:
    c = _hsv(rng.random(), rng.uniform(0.0, 1.0), rng.uniform(0.1, 1.0))
    return (int(c[0]), int(c[1]), int(c[2]))


def _base_color(rng: np.random.Generator, kind: str) -> np.ndarray:
    if kind == "floor" and rng.random() < 0.5:
        return _hsv(rng.uniform(0.05, 0.11), rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.75))
    if rng.random() < 0.5:  # painted wall / plain surface: pale
        return _hsv(rng.random(), rng.uniform(0.0, 0.35), rng.uniform(0.55, 0.95))
    return _hsv(rng.random(), rng.uniform(0.1, 0.8), rng.uniform(0.2, 0.9))


def _low_freq(rng: np.random.Generator, h: int, w: int, cells: float) -> np.ndarray:
    """Smooth noise in ``[-1, 1]``, ``float32 [h, w]``, about ``cells`` blobs across."""
    gh = max(int(cells * h / max(h, w)), 1) + 2
    gw = max(int(cells * w / max(h, w)), 1) + 2
    grid = rng.uniform(-1.0, 1.0, (gh, gw)).astype(np.float32)
    return cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)


def _pattern(
    rng: np.random.Generator, h: int, w: int, px_per_m: float, kind: str
) -> np.ndarray | None:
    """Multiplicative pattern ``float32 [h, w]`` around 1 (stripes, tiles, bricks, planks)."""
    choice = int(rng.integers(5))
    if choice == 0:
        return None
    xs = np.arange(w, dtype=np.float32)[None, :] / px_per_m
    ys = np.arange(h, dtype=np.float32)[:, None] / px_per_m
    depth = rng.uniform(0.06, 0.25)
    if choice == 1:  # stripes (wallpaper) or planks (floor)
        period = rng.uniform(0.08, 0.4)
        coord = ys if kind == "floor" and rng.random() < 0.5 else xs
        band = ((coord / period) % 1.0) < rng.uniform(0.3, 0.7)
        out = np.where(band, 1.0 - depth, 1.0 + depth * 0.5)
        return np.broadcast_to(out, (h, w)).astype(np.float32)
    if choice == 2:  # tiles: grid lines
        period, line = rng.uniform(0.2, 0.6), rng.uniform(0.008, 0.02)
        grid = ((xs % period) < line) | ((ys % period) < line)
        return np.where(grid, 1.0 - 2 * depth, 1.0).astype(np.float32)
    if choice == 3:  # bricks / planks with staggered joints
        bh, bw = rng.uniform(0.06, 0.12), rng.uniform(0.2, 0.5)
        row = np.floor(ys / bh)
        shifted = xs + (row % 2) * bw / 2
        joint = ((ys % bh) < 0.012) | ((shifted % bw) < 0.012)
        return np.where(joint, 1.0 - 2 * depth, 1.0).astype(np.float32)
    period = rng.uniform(0.15, 0.5)  # checker
    check = (np.floor(xs / period) + np.floor(ys / period)) % 2 == 0
    return np.where(check, 1.0 - depth, 1.0 + depth * 0.5).astype(np.float32)


def _clutter(rng: np.random.Generator, tex: np.ndarray, px_per_m: float, density: float) -> None:
    """Draw random unannotated clutter into ``tex`` (``float32 [h, w, 3]``) in place."""
    h, w = tex.shape[:2]
    area_m2 = h * w / px_per_m**2
    n = int(rng.poisson(density * area_m2)) + int(rng.integers(2, 6))
    for _ in range(n):
        kind = int(rng.integers(6))
        color = _rand_color(rng)
        c = (int(rng.integers(w)), int(rng.integers(h)))
        size = max(rng.uniform(0.04, 0.5) * px_per_m, 2.0)
        if kind == 0:  # straight line (edge, cable, shelf)
            ang = rng.uniform(0, np.pi)
            d = size * rng.uniform(1.0, 4.0) * np.array([np.cos(ang), np.sin(ang)])
            p0 = (int(c[0] - d[0]), int(c[1] - d[1]))
            p1 = (int(c[0] + d[0]), int(c[1] + d[1]))
            th = max(int(rng.uniform(0.004, 0.04) * px_per_m), 1)
            cv2.line(tex, p0, p1, color, th, cv2.LINE_8)
        elif kind == 1:  # blob / stain
            axes = (max(int(size), 1), max(int(size * rng.uniform(0.3, 1.0)), 1))
            cv2.ellipse(tex, c, axes, rng.uniform(0, 180), 0, 360, color, -1, cv2.LINE_8)
        elif kind == 2:  # random polygon (hard negative shape)
            k = int(rng.integers(3, 8))
            ang = np.sort(rng.uniform(0, 2 * np.pi, k))
            rad = size * rng.uniform(0.4, 1.0, k)
            pts = np.stack([c[0] + rad * np.cos(ang), c[1] + rad * np.sin(ang)], 1)
            cv2.fillPoly(tex, [pts.astype(np.int32)], color, cv2.LINE_8)
        elif kind == 3:  # poster / picture frame
            pw, ph = size * rng.uniform(0.8, 2.0), size * rng.uniform(0.8, 2.0)
            p0 = (int(c[0] - pw / 2), int(c[1] - ph / 2))
            p1 = (int(c[0] + pw / 2), int(c[1] + ph / 2))
            cv2.rectangle(tex, p0, p1, color, -1)
            cv2.rectangle(tex, p0, p1, _rand_color(rng), max(int(size * 0.08), 1))
        elif kind == 4:  # cable: random walk polyline
            steps = rng.normal(0, size * 0.4, (int(rng.integers(4, 12)), 2)).cumsum(0)
            pts = (np.array(c) + steps).astype(np.int32)
            th = max(int(rng.uniform(0.005, 0.02) * px_per_m), 1)
            cv2.polylines(tex, [pts], False, color, th, cv2.LINE_8)
        else:  # ring (a disc-like distractor that is not a ball)
            th = max(int(size * rng.uniform(0.1, 0.3)), 1)
            cv2.circle(tex, c, max(int(size * 0.6), 1), color, th, cv2.LINE_8)


def make_texture(
    rng: np.random.Generator,
    width: int,
    height: int,
    px_per_m: float,
    kind: str = "wall",
    clutter: float = 1.0,
) -> np.ndarray:
    """A ``uint8 [height, width, 3]`` RGB surface texture at ``px_per_m`` pixels per metre.

    Base colour, gentle gradient, smooth low-frequency variation, an optional regular pattern,
    unannotated clutter (``clutter`` items per square metre on average) and fine grain.
    """
    h, w = int(height), int(width)
    base = _base_color(rng, kind)
    field = np.ones((h, w), np.float32)
    field += rng.uniform(0.05, 0.25) * _low_freq(rng, h, w, rng.uniform(2, 8))
    ang = rng.uniform(0, 2 * np.pi)
    xs = np.linspace(-1, 1, w, dtype=np.float32)[None, :]
    ys = np.linspace(-1, 1, h, dtype=np.float32)[:, None]
    field += np.float32(rng.uniform(0.0, 0.2)) * (xs * np.cos(ang) + ys * np.sin(ang))
    pattern = _pattern(rng, h, w, px_per_m, kind)
    if pattern is not None:
        field *= pattern
    # slowly varying tint around the base colour, made at low resolution
    tint = 1.0 + rng.uniform(-0.08, 0.08, (4, 4, 3)).astype(np.float32)
    color = cv2.resize(tint * base, (w, h), interpolation=cv2.INTER_LINEAR)
    tex = color * field[..., None]
    _clutter(rng, tex, px_per_m, clutter * rng.uniform(0.3, 1.5))
    tex += rng.standard_normal((h, w, 1), dtype=np.float32) * np.float32(rng.uniform(1.0, 6.0))
    return np.clip(tex, 0, 255).astype(np.uint8)
