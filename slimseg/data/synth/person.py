"""The articulated person: a two-segment-limbed figure, front or side view, and its walking gait.

:func:`sample_person` fixes build, colours and a random pose (front view with raised or
lowered arms and legs apart, or side view mid-stride); :func:`walking_pose` gives the joint
angles of a side-view gait, which sequences apply frame by frame to a sampled style.
:func:`draw_person` paints the figure into a :class:`~slimseg.data.synth.painter.Painter`
centred at ``(cx, cy)``, ``size`` pixels tall. Limb angles are radians from straight down in
the local frame (:class:`~slimseg.data.synth.style.LocalFrame`), ``_1`` upper and ``_2``
lower segment.
"""

from __future__ import annotations

import numpy as np

from slimseg.data.synth.painter import Painter
from slimseg.data.synth.style import LocalFrame, Style, any_color, pick, scale

_SKIN = ((255, 219, 172), (241, 194, 125), (224, 172, 105), (198, 134, 66), (141, 85, 36))
_HAIR = ((20, 15, 10), (60, 40, 25), (110, 70, 40), (200, 160, 90), (150, 150, 150))


def sample_person(rng: np.random.Generator) -> Style:
    """A random person: skin, hair and clothes colours, build, head size, and a still pose
    (side view mid-stride 40 % of the time, else front view with limbs spread)."""
    profile = float(rng.random() < 0.4)
    build = rng.uniform(0.8, 1.3)
    shirt = any_color(rng)
    colors = {
        "skin": pick(rng, _SKIN),
        "hair": pick(rng, _HAIR),
        "shirt": shirt,
        "pants": scale(any_color(rng), 0.7),
        "shoes": scale(any_color(rng), 0.35),
    }
    colors["sleeve"] = shirt if rng.random() < 0.5 else colors["skin"]
    colors["shin"] = colors["pants"] if rng.random() < 0.75 else colors["skin"]
    params = {
        "profile": profile,
        "build": build,
        "head": rng.uniform(0.058, 0.075),
        "flip": float(rng.choice([-1.0, 1.0])),
        "tilt": rng.normal(0.0, 0.05),
        "hair_long": float(rng.random() < 0.3),
        "shade_dir": rng.uniform(0, 2 * np.pi),
        "shade_gain": rng.uniform(0.05, 0.3),
    }
    if profile:
        swing = rng.uniform(-0.7, 0.7)
        params |= {
            "arm_l1": swing,
            "arm_l2": swing + rng.uniform(0.0, 1.3),
            "arm_r1": -swing + rng.normal(0, 0.2),
            "arm_r2": -swing + rng.uniform(0.0, 1.3),
            "leg_l1": -0.8 * swing,
            "leg_l2": -0.8 * swing - rng.uniform(0.0, 1.0),
            "leg_r1": 0.8 * swing,
            "leg_r2": 0.8 * swing - rng.uniform(0.0, 0.6),
        }
    else:
        abd_l, abd_r = rng.uniform(0.05, 2.7, 2)
        hip_l, hip_r = rng.uniform(-0.05, 0.45, 2)
        params |= {
            "arm_l1": -abd_l,
            "arm_l2": -abd_l + rng.uniform(-1.4, 1.4),
            "arm_r1": abd_r,
            "arm_r2": abd_r + rng.uniform(-1.4, 1.4),
            "leg_l1": -hip_l,
            "leg_l2": -hip_l + rng.uniform(-0.5, 0.5),
            "leg_r1": hip_r,
            "leg_r2": hip_r + rng.uniform(-0.5, 0.5),
        }
    return Style("person", colors, params)


def walking_pose(phase: float, amplitude: float = 0.45) -> dict[str, float]:
    """Joint angles of a side-view walking gait at ``phase`` (radians, one stride = 2*pi)."""
    s, c = np.sin(phase), np.cos(phase)
    knee_l = 0.9 * amplitude * max(0.0, c) + 0.1
    knee_r = 0.9 * amplitude * max(0.0, -c) + 0.1
    return {
        "profile": 1.0,
        "leg_l1": amplitude * s,
        "leg_l2": amplitude * s - knee_l,
        "leg_r1": -amplitude * s,
        "leg_r2": -amplitude * s - knee_r,
        "arm_l1": -0.8 * amplitude * s,
        "arm_l2": -0.8 * amplitude * s + 0.35,
        "arm_r1": 0.8 * amplitude * s,
        "arm_r2": 0.8 * amplitude * s + 0.35,
    }


def _chain(root: np.ndarray, a1: float, l1: float, a2: float, l2: float) -> list[np.ndarray]:
    """Joint positions of a two-segment limb hanging from ``root`` (angles from straight down)."""
    j1 = root + l1 * np.array([np.sin(a1), np.cos(a1)])
    j2 = j1 + l2 * np.array([np.sin(a2), np.cos(a2)])
    return [root, j1, j2]


def draw_person(pt: Painter, st: Style, cx: float, cy: float, size: float) -> None:
    """Paint person ``st`` into ``pt`` centred at frame pixel ``(cx, cy)``, ``size`` px tall:
    back leg (and, in side view, back arm, both dimmed), front leg, torso, arms, head and
    hair, then a linear shading over the whole figure."""
    p, col = st.params, st.colors
    t = LocalFrame(cx, cy, size, p["tilt"], p["flip"])
    b, hr = p["build"], p["head"]
    prof = p["profile"] > 0.5
    sw, hw = (0.02, 0.015) if prof else (0.105 * b, 0.075 * b)
    tw_top, tw_bot = (0.06 * b, 0.055 * b) if prof else (0.13 * b, 0.1 * b)
    y_sh, y_hip = -0.5 + 2 * hr + 0.035, 0.02
    w_ua, w_fa, w_th, w_sh = 0.05 * b, 0.042 * b, 0.078 * b, 0.058 * b

    def limb_pts(side: str, kind: str) -> list[np.ndarray]:
        sign = -1.0 if side == "l" else 1.0
        if kind == "arm":
            root = np.array([sign * sw, y_sh + 0.02])
            return _chain(root, p[f"arm_{side}1"], 0.16, p[f"arm_{side}2"], 0.15)
        root = np.array([sign * hw, y_hip])
        return _chain(root, p[f"leg_{side}1"], 0.245, p[f"leg_{side}2"], 0.235)

    def draw_leg(side: str, dim: float) -> None:
        hip, knee, ankle = (t.p(*q) for q in limb_pts(side, "leg"))
        sign = 1.0 if prof else (-1.0 if side == "l" else 1.0)
        toe = ankle + (t.p(sign * 0.065, 0.0) - t.p(0.0, 0.0))
        pt.limb(ankle, toe, t.s(0.045), t.s(0.035), scale(col["shoes"], dim))
        pt.limb(knee, ankle, t.s(w_sh), t.s(w_sh * 0.85), scale(col["shin"], dim))
        pt.limb(hip, knee, t.s(w_th), t.s(w_sh), scale(col["pants"], dim))

    def draw_arm(side: str, dim: float) -> None:
        sh, el, wr = (t.p(*q) for q in limb_pts(side, "arm"))
        pt.limb(el, wr, t.s(w_fa), t.s(w_fa * 0.8), scale(col["sleeve"], dim))
        pt.circle(wr, t.s(0.027 * b), scale(col["skin"], dim))
        pt.limb(sh, el, t.s(w_ua), t.s(w_fa), scale(col["shirt"], dim))

    far = 0.8 if prof else 1.0
    draw_leg("r", far)
    if prof:
        draw_arm("r", far)
    draw_leg("l", 1.0)
    torso = t((-tw_top, y_sh), (tw_top, y_sh), (tw_bot, y_hip + 0.03), (-tw_bot, y_hip + 0.03))
    pt.poly(torso, col["shirt"])
    pt.poly(
        t(
            (-tw_bot, y_hip - 0.02),
            (tw_bot, y_hip - 0.02),
            (tw_bot, y_hip + 0.05),
            (-tw_bot, y_hip + 0.05),
        ),
        col["pants"],
    )
    if not prof:
        draw_arm("r", 1.0)
    draw_arm("l", 1.0)
    head = t.p(0.015 if prof else 0.0, -0.5 + hr)
    pt.limb(
        t.p(0.0, -0.5 + 1.6 * hr), t.p(0.0, y_sh + 0.01), t.s(0.045 * b), t.s(0.05 * b), col["skin"]
    )
    if p["hair_long"] > 0.5:
        pt.limb(
            head,
            t.p(-0.02 if prof else 0.0, -0.5 + 2.6 * hr),
            t.s(2 * hr),
            t.s(1.8 * hr),
            col["hair"],
        )
    pt.circle(head, t.s(hr), col["skin"])
    ang = np.degrees(np.arctan2(t.m[1, 0], t.m[0, 0]))
    pt.ellipse(head, (t.s(hr * 1.05), t.s(hr * 1.05)), ang, col["hair"], arc=(180.0, 360.0))
    pt.shade_linear(np.array([cx, cy]), p["shade_dir"], size / 2, p["shade_gain"])
