"""A small drawing surface for one instance: colour layer and exact binary mask drawn together.

Every primitive is filled with ``cv2`` at 1/16-pixel precision (``shift=4``) and without
anti-aliasing, so the mask is exactly the set of pixels that received the instance's colour.
The painter covers a square patch of the frame (``x0, y0`` is its top-left corner in frame
pixels); callers pass frame coordinates and the painter translates them.
"""

from __future__ import annotations

import cv2
import numpy as np

_SHIFT = 4
_ONE = 1 << _SHIFT

Color = tuple[int, int, int]


def _fixed(xy: np.ndarray) -> np.ndarray:
    """``float [N, 2]`` pixel coordinates -> ``int32 [N, 2]`` fixed point for ``shift=4``."""
    return np.round(np.asarray(xy, np.float64) * _ONE).astype(np.int32)


def _fix1(v: float) -> int:
    """One length in pixels -> fixed point."""
    return int(np.rint(float(v) * _ONE))


class Painter:
    """Colour patch ``rgb`` (``uint8 [h, w, 3]``) and mask ``mask`` (``uint8 [h, w]``, 0/255).

    The patch covers frame pixels ``x0 <= x < x0 + w`` and ``y0 <= y < y0 + h``.
    """

    def __init__(self, x0: int, y0: int, w: int, h: int) -> None:
        self.x0, self.y0 = int(x0), int(y0)
        self.rgb = np.zeros((h, w, 3), np.uint8)
        self.mask = np.zeros((h, w), np.uint8)

    def _local(self, pts: np.ndarray) -> np.ndarray:
        pts = np.asarray(pts, np.float64).reshape(-1, 2)
        return _fixed(pts - (self.x0, self.y0))

    # -- filled primitives (colour + mask) -------------------------------------------------
    def poly(self, pts: np.ndarray, color: Color, mask: bool = True) -> None:
        """Filled polygon through ``float [N, 2]`` frame points."""
        p = [self._local(pts)]
        cv2.fillPoly(self.rgb, p, color, cv2.LINE_8, _SHIFT)
        if mask:
            cv2.fillPoly(self.mask, p, 255, cv2.LINE_8, _SHIFT)

    def circle(self, center: np.ndarray, radius: float, color: Color, mask: bool = True) -> None:
        """Filled disc; ``radius`` in pixels (at least half a pixel is drawn)."""
        c = tuple(int(v) for v in self._local(center)[0])
        r = max(_fix1(radius), _ONE // 2)
        cv2.circle(self.rgb, c, r, color, -1, cv2.LINE_8, _SHIFT)
        if mask:
            cv2.circle(self.mask, c, r, 255, -1, cv2.LINE_8, _SHIFT)

    def ellipse(
        self,
        center: np.ndarray,
        axes: tuple[float, float],
        angle_deg: float,
        color: Color,
        arc: tuple[float, float] = (0.0, 360.0),
        mask: bool = True,
    ) -> None:
        """Filled ellipse (or sector, via ``arc`` in degrees) with half-axes ``axes`` in px."""
        c = tuple(int(v) for v in self._local(center)[0])
        ax = (
            max(_fix1(axes[0]), _ONE // 2),
            max(_fix1(axes[1]), _ONE // 2),
        )
        args = (c, ax, float(angle_deg), float(arc[0]), float(arc[1]))
        cv2.ellipse(self.rgb, *args, color, -1, cv2.LINE_8, _SHIFT)
        if mask:
            cv2.ellipse(self.mask, *args, 255, -1, cv2.LINE_8, _SHIFT)

    def limb(
        self, p0: np.ndarray, p1: np.ndarray, w0: float, w1: float, color: Color, mask: bool = True
    ) -> None:
        """Tapered segment from ``p0`` (width ``w0`` px) to ``p1`` (width ``w1``), round ends."""
        p0 = np.asarray(p0, np.float64)
        p1 = np.asarray(p1, np.float64)
        d = p1 - p0
        n = float(np.hypot(*d))
        normal = np.array([-d[1], d[0]]) / n if n > 1e-6 else np.array([1.0, 0.0])
        quad = np.stack(
            [p0 + normal * w0 / 2, p1 + normal * w1 / 2, p1 - normal * w1 / 2, p0 - normal * w0 / 2]
        )
        self.poly(quad, color, mask)
        self.circle(p0, w0 / 2, color, mask)
        self.circle(p1, w1 / 2, color, mask)

    def line(self, p0: np.ndarray, p1: np.ndarray, width: float, color: Color) -> None:
        """Surface detail: a straight band drawn on the colour layer only (mask untouched)."""
        self.limb(p0, p1, width, width, color, mask=False)

    # -- shading over the whole patch -------------------------------------------------------
    def _grid(self) -> tuple[np.ndarray, np.ndarray]:
        h, w = self.mask.shape
        ys = np.arange(h, dtype=np.float32)[:, None] + self.y0
        xs = np.arange(w, dtype=np.float32)[None, :] + self.x0
        return xs, ys

    def shade(self, factor: np.ndarray) -> None:
        """Multiply the colour layer by ``float32 [h, w]`` (broadcastable) gains."""
        out = self.rgb.astype(np.float32) * np.asarray(factor, np.float32)[..., None]
        self.rgb = np.clip(out, 0, 255).astype(np.uint8)

    def shade_linear(self, center: np.ndarray, direction: float, scale: float, gain: float) -> None:
        """Brightness ramp ``1 + gain * t`` with ``t`` the signed distance / ``scale`` along
        ``direction`` (radians) from ``center``."""
        xs, ys = self._grid()
        t = ((xs - center[0]) * np.cos(direction) + (ys - center[1]) * np.sin(direction)) / scale
        self.shade(1.0 + gain * np.clip(t, -1.0, 1.0))

    def shade_radial(self, highlight: np.ndarray, radius: float, strength: float) -> None:
        """Sphere-like shading: bright at ``highlight``, darker by ``strength`` at ``radius``."""
        xs, ys = self._grid()
        r = np.sqrt((xs - highlight[0]) ** 2 + (ys - highlight[1]) ** 2) / max(radius, 1e-3)
        r = np.clip(r, 0.0, 1.6)
        self.shade(1.15 - strength * r * np.sqrt(r))  # r ** 1.5 without the CPU-dependent pow
