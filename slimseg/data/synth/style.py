"""What every category renderer shares: the ``Style`` record, the local object frame, colours.

A ``Style`` fixes everything random about one object (colours, proportions, pose) once, so a
sequence can redraw the same object every frame. Renderers describe shapes in a
:class:`LocalFrame` in units of the object's height (x right, y down, the object spanning y in
[-0.5, 0.5]); ``flip`` mirrors x and ``tilt`` rotates the whole object (radians). Colours are
RGB ``uint8`` triples (:data:`~slimseg.data.synth.painter.Color`).
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field, replace

import numpy as np

from slimseg.data.synth.painter import Color


@dataclass(frozen=True)
class Style:
    """Everything random about one object: ``colors`` (RGB uint8 triples) and ``params``."""

    category: str
    colors: dict[str, Color] = field(default_factory=dict)
    params: dict[str, float] = field(default_factory=dict)

    def with_params(self, **params: float) -> Style:
        """A copy with some ``params`` replaced (e.g. a new pose for the next frame)."""
        return replace(self, params={**self.params, **params})


class LocalFrame:
    """Local object frame (units of height) -> frame pixels.

    Centred at frame pixel ``(cx, cy)``, ``size`` pixels per unit, x mirrored by ``flip``
    (+1 or -1), then rotated by ``tilt`` radians; ``m`` is the ``float64 [2, 2]`` local ->
    pixel matrix.
    """

    def __init__(self, cx: float, cy: float, size: float, tilt: float, flip: float) -> None:
        self.c = np.array([cx, cy], np.float64)
        self.size = float(size)
        ca, sa = np.cos(tilt), np.sin(tilt)
        self.m = np.array([[ca * flip, -sa], [sa * flip, ca]]) * self.size

    def __call__(self, *pts: tuple[float, float]) -> np.ndarray:
        """N local points -> ``float64 [N, 2]`` frame pixels."""
        return np.asarray(pts, np.float64) @ self.m.T + self.c

    def p(self, x: float, y: float) -> np.ndarray:
        """One local point -> ``float64 [2]`` frame pixel."""
        return self((x, y))[0]

    def s(self, length: float) -> float:
        """A local length -> pixels."""
        return length * self.size


def _hsv(h: float, s: float, v: float) -> Color:
    r, g, b = colorsys.hsv_to_rgb(h % 1.0, float(np.clip(s, 0, 1)), float(np.clip(v, 0, 1)))
    return (int(r * 255), int(g * 255), int(b * 255))


def any_color(rng: np.random.Generator) -> Color:
    """A random colour, neither too grey nor too dark."""
    return _hsv(rng.random(), rng.uniform(0.2, 1.0), rng.uniform(0.25, 1.0))


def scale(c: Color, f: float) -> Color:
    """``c`` with every channel multiplied by ``f`` (clipped to 0-255)."""
    return tuple(int(np.clip(v * f, 0, 255)) for v in c)  # type: ignore[return-value]


def jitter(rng: np.random.Generator, c: Color, amount: int = 18) -> Color:
    """``c`` with every channel moved by a random integer in ``[-amount, amount]``."""
    d = rng.integers(-amount, amount + 1, 3)
    return tuple(int(np.clip(v + dv, 0, 255)) for v, dv in zip(c, d, strict=True))  # type: ignore[return-value]


def pick(rng: np.random.Generator, palette: tuple[Color, ...]) -> Color:
    """A jittered colour drawn from ``palette``."""
    return jitter(rng, palette[int(rng.integers(len(palette)))])
