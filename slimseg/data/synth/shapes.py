"""Category renderers: random shape/appearance (a ``Style``) and drawing it at a given place.

Each category has a sampler ``style = sample_style(name, rng)`` that fixes colours, proportions
and pose once (so a sequence can redraw the same object every frame), and a drawer that paints
the style into a :class:`~slimseg.data.synth.painter.Painter` centred at ``(cx, cy)`` with
``size`` = the object's nominal height in pixels (shapes are described in a
:class:`~slimseg.data.synth.style.LocalFrame`). The rigid categories (dog, sports ball,
bottle, chair, tv) live here; the articulated person in :mod:`slimseg.data.synth.person`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from slimseg.data.synth.categories import BY_NAME
from slimseg.data.synth.painter import Color, Painter
from slimseg.data.synth.person import draw_person, sample_person
from slimseg.data.synth.style import LocalFrame, Style, any_color, jitter, pick, scale

# Half-size of the square patch an instance can cover, in units of its height.
PATCH_REACH = 0.95

_FUR = ((120, 80, 40), (30, 25, 20), (200, 170, 120), (230, 225, 215), (160, 110, 60))
_WOOD = ((133, 94, 66), (160, 120, 80), (102, 68, 45), (193, 154, 107))


# -- dog -------------------------------------------------------------------------------------
def _sample_dog(rng: np.random.Generator) -> Style:
    fur = pick(rng, _FUR)
    colors = {"fur": fur, "patch": pick(rng, _FUR), "nose": (25, 20, 20)}
    colors["ear"] = scale(fur, rng.uniform(0.6, 1.0))
    params = {
        "flip": float(rng.choice([-1.0, 1.0])),
        "tilt": rng.normal(0.0, 0.04),
        "body_len": rng.uniform(0.34, 0.46),
        "body_h": rng.uniform(0.13, 0.19),
        "leg_w": rng.uniform(0.06, 0.09),
        "tail": rng.uniform(-2.6, -0.6),
        "ears_up": float(rng.random() < 0.5),
        "spots": float(rng.random() < 0.4),
        "shade_gain": rng.uniform(0.05, 0.3),
    }
    for k in ("fl", "fr", "bl", "br"):
        params[f"leg_{k}"] = rng.uniform(-0.45, 0.45)
    return Style("dog", colors, params)


def _draw_dog(pt: Painter, st: Style, cx: float, cy: float, size: float) -> None:
    p, col = st.params, st.colors
    t = LocalFrame(cx, cy, size, p["tilt"], p["flip"])
    bl, bh, lw = p["body_len"], p["body_h"], p["leg_w"]
    by = -0.05
    ang = np.degrees(np.arctan2(t.m[1, 0], t.m[0, 0]))

    def leg(x: float, a: float, dim: float) -> None:
        top = np.array([x, by + 0.05])
        foot = top + 0.45 * np.array([np.sin(a), np.cos(a)])
        c = scale(col["fur"], dim)
        pt.limb(t.p(*top), t.p(*foot), t.s(lw), t.s(lw * 0.8), c)

    leg(bl * 0.75 + 0.04, p["leg_fr"], 0.75)
    leg(-bl * 0.75 + 0.04, p["leg_br"], 0.75)
    tail_root = np.array([-bl * 0.95, by - 0.05])
    tail_tip = tail_root + 0.28 * np.array([np.sin(p["tail"]), np.cos(p["tail"])])
    pt.limb(t.p(*tail_root), t.p(*tail_tip), t.s(0.05), t.s(0.025), col["fur"])
    pt.ellipse(t.p(0.0, by), (t.s(bl), t.s(bh)), ang, col["fur"])
    if p["spots"] > 0.5:
        pt.ellipse(
            t.p(-bl * 0.3, by - bh * 0.2),
            (t.s(bl * 0.35), t.s(bh * 0.6)),
            ang,
            col["patch"],
            mask=False,
        )
    leg(bl * 0.75, p["leg_fl"], 1.0)
    leg(-bl * 0.75, p["leg_bl"], 1.0)
    head = np.array([bl + 0.12, -0.33])
    pt.limb(t.p(bl * 0.7, by - 0.02), t.p(*head), t.s(0.16), t.s(0.12), col["fur"])
    pt.circle(t.p(*head), t.s(0.13), col["fur"])
    snout = head + (0.14, 0.05)
    pt.ellipse(t.p(*snout), (t.s(0.1), t.s(0.06)), ang, col["fur"])
    pt.circle(t.p(snout[0] + 0.08, snout[1] - 0.02), t.s(0.025), col["nose"])
    if p["ears_up"] > 0.5:
        pt.poly(
            t(
                (head[0] - 0.1, head[1] - 0.06),
                (head[0] - 0.02, head[1] - 0.1),
                (head[0] - 0.08, -0.5),
            ),
            col["ear"],
        )
    else:
        pt.ellipse(t.p(head[0] - 0.08, head[1] + 0.02), (t.s(0.04), t.s(0.1)), ang + 15, col["ear"])
    pt.shade_linear(np.array([cx, cy]), np.pi / 2, size / 2, -p["shade_gain"])


# -- sports ball -----------------------------------------------------------------------------
def _sample_ball(rng: np.random.Generator) -> Style:
    c1 = any_color(rng)
    c2 = any_color(rng) if rng.random() < 0.6 else (240, 240, 240)
    params = {
        "pattern": float(rng.integers(4)),  # 0 plain, 1 stripes, 2 halves, 3 spots
        "angle": rng.uniform(0, np.pi),
        "bands": float(rng.integers(1, 4)),
        "band_w": rng.uniform(0.06, 0.16),
        "hl_dir": rng.uniform(0, 2 * np.pi),
        "hl_off": rng.uniform(0.15, 0.4),
        "strength": rng.uniform(0.3, 0.6),
        "spot_seed": float(rng.integers(1 << 30)),
    }
    return Style("sports ball", {"c1": c1, "c2": c2}, params)


def _draw_ball(pt: Painter, st: Style, cx: float, cy: float, size: float) -> None:
    p, col = st.params, st.colors
    r = size / 2
    c = np.array([cx, cy])
    pt.circle(c, r, col["c1"])
    pattern = int(p["pattern"])
    a = p["angle"]
    u, n = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    if pattern == 1:
        k = int(p["bands"])
        for i in range(k):
            off = (i - (k - 1) / 2) * 0.45 * r
            pt.line(
                c + n * off - 1.2 * r * u, c + n * off + 1.2 * r * u, p["band_w"] * size, col["c2"]
            )
    elif pattern == 2:
        pt.ellipse(c, (r, r), np.degrees(a), col["c2"], arc=(0.0, 180.0), mask=False)
    elif pattern == 3:
        srng = np.random.default_rng(int(p["spot_seed"]))
        for _ in range(int(srng.integers(3, 8))):
            rad, ang = r * 0.75 * np.sqrt(srng.random()), srng.uniform(0, 2 * np.pi)
            pos = c + rad * np.array([np.cos(ang), np.sin(ang)])
            pt.circle(pos, r * srng.uniform(0.1, 0.22), col["c2"], mask=False)
    hl = c + p["hl_off"] * r * np.array([np.cos(p["hl_dir"]), np.sin(p["hl_dir"])])
    pt.shade_radial(hl, 1.5 * r, p["strength"])


# -- bottle ----------------------------------------------------------------------------------
def _sample_bottle(rng: np.random.Generator) -> Style:
    glass = (
        ((40, 110, 50), (110, 60, 20), (60, 120, 190), (200, 210, 215))[int(rng.integers(4))]
        if rng.random() < 0.6
        else any_color(rng)
    )
    colors = {"body": jitter(rng, glass), "cap": any_color(rng), "label": any_color(rng)}
    lying = rng.random() < 0.25
    params = {
        "bw": rng.uniform(0.1, 0.19),
        "nw": rng.uniform(0.035, 0.06),
        "shoulder": rng.uniform(-0.2, -0.05),
        "neck": rng.uniform(-0.38, -0.3),
        "label": float(rng.random() < 0.7),
        "tilt": rng.uniform(-np.pi / 2, np.pi / 2) if lying else rng.normal(0.0, 0.08),
        "flip": 1.0,
        "shade_gain": rng.uniform(0.15, 0.4),
    }
    return Style("bottle", colors, params)


def _draw_bottle(pt: Painter, st: Style, cx: float, cy: float, size: float) -> None:
    p, col = st.params, st.colors
    t = LocalFrame(cx, cy, size, p["tilt"], p["flip"])
    bw, nw, ysh, yn = p["bw"], p["nw"], p["shoulder"], p["neck"]
    rc = min(0.05, bw * 0.5)
    pt.poly(
        t((-bw, ysh), (bw, ysh), (bw, 0.5 - rc), (bw - rc, 0.5), (-bw + rc, 0.5), (-bw, 0.5 - rc)),
        col["body"],
    )
    pt.poly(t((-bw, ysh + 0.001), (-nw, yn), (nw, yn), (bw, ysh + 0.001)), col["body"])
    pt.poly(t((-nw, yn + 0.01), (-nw, -0.45), (nw, -0.45), (nw, yn + 0.01)), col["body"])
    pt.poly(
        t((-nw * 1.2, -0.45), (-nw * 1.2, -0.5), (nw * 1.2, -0.5), (nw * 1.2, -0.45)), col["cap"]
    )
    if p["label"] > 0.5:
        y0 = ysh + 0.12
        pt.poly(t((-bw, y0), (bw, y0), (bw, y0 + 0.22), (-bw, y0 + 0.22)), col["label"], False)
    hl = scale(col["body"], 1.35)
    pt.line(t.p(-bw * 0.45, ysh + 0.04), t.p(-bw * 0.45, 0.45), t.s(bw * 0.25), hl)
    ang = p["tilt"]
    pt.shade_linear(np.array([cx, cy]), ang, t.s(bw), p["shade_gain"])


# -- chair -----------------------------------------------------------------------------------
def _sample_chair(rng: np.random.Generator) -> Style:
    base = pick(rng, _WOOD) if rng.random() < 0.6 else any_color(rng)
    colors = {"frame": base, "seat": jitter(rng, scale(base, rng.uniform(0.8, 1.2)), 25)}
    params = {
        "side": float(rng.random() < 0.5),
        "flip": float(rng.choice([-1.0, 1.0])),
        "tilt": rng.normal(0.0, 0.03),
        "seat_y": rng.uniform(-0.02, 0.08),
        "seat_w": rng.uniform(0.42, 0.58),
        "leg_w": rng.uniform(0.03, 0.05),
        "slats": float(rng.random() < 0.5),
        "lean": rng.uniform(0.0, 0.08),
        "splay": rng.uniform(0.0, 0.06),
        "shade_dir": rng.uniform(0, 2 * np.pi),
        "shade_gain": rng.uniform(0.05, 0.25),
    }
    return Style("chair", colors, params)


def _draw_chair(pt: Painter, st: Style, cx: float, cy: float, size: float) -> None:
    p, col = st.params, st.colors
    t = LocalFrame(cx, cy, size, p["tilt"], p["flip"])
    ys, hw, lw, sp = p["seat_y"], p["seat_w"] / 2, p["leg_w"], p["splay"]
    st_h = 0.05
    frame, dark = col["frame"], scale(col["frame"], 0.7)

    def leg(x: float, dx: float, y_end: float, c: Color) -> None:
        pt.limb(t.p(x, ys + st_h), t.p(x + dx, y_end), t.s(lw), t.s(lw * 0.85), c)

    if p["side"] > 0.5:  # side view, backrest on the -x side
        off = 0.07
        leg(-hw + lw + off, -sp, 0.45, dark)
        leg(hw - lw + off, sp, 0.45, dark)
        leg(-hw + lw, -sp, 0.5 - lw / 2, frame)
        leg(hw - lw, sp, 0.5 - lw / 2, frame)
        pt.poly(t((-hw, ys), (-hw + off, ys - 0.05), (hw + off, ys - 0.05), (hw, ys)), col["seat"])
        pt.poly(t((-hw, ys), (hw, ys), (hw, ys + st_h), (-hw, ys + st_h)), frame)
        top = (-hw - p["lean"], -0.5 + lw / 2)
        pt.limb(t.p(-hw + lw / 2, ys), t.p(*top), t.s(lw * 1.2), t.s(lw * 1.1), frame)
        pt.limb(
            t.p(-hw + lw / 2 + off, ys - 0.05),
            t.p(top[0] + off, top[1] + 0.02),
            t.s(lw),
            t.s(lw),
            dark,
        )
    else:  # front view, backrest panel behind the seat
        bw = hw * 0.85
        top = -0.5
        for x in (-bw, bw):
            pt.limb(t.p(x, ys), t.p(x, top + lw / 2), t.s(lw * 1.2), t.s(lw * 1.2), frame)
        if p["slats"] > 0.5:
            for y in (top + 0.04, top + 0.2):
                pt.poly(t((-bw, y), (bw, y), (bw, y + 0.07), (-bw, y + 0.07)), frame)
        else:
            pt.poly(
                t((-bw, top + 0.02), (bw, top + 0.02), (bw, ys - 0.12), (-bw, ys - 0.12)),
                col["seat"],
            )
        leg(-bw + lw, 0.0, 0.43, dark)
        leg(bw - lw, 0.0, 0.43, dark)
        pt.poly(
            t((-hw, ys - 0.04), (hw, ys - 0.04), (hw, ys + st_h), (-hw, ys + st_h)), col["seat"]
        )
        leg(-hw + lw / 2, -sp, 0.5 - lw / 2, frame)
        leg(hw - lw / 2, sp, 0.5 - lw / 2, frame)
    pt.shade_linear(np.array([cx, cy]), p["shade_dir"], size / 2, p["shade_gain"])


# -- tv --------------------------------------------------------------------------------------
def _sample_tv(rng: np.random.Generator) -> Style:
    colors = {
        "bezel": jitter(rng, (25, 25, 28), 15),
        "screen_a": any_color(rng),
        "screen_b": any_color(rng),
        "stand": jitter(rng, (50, 50, 55), 20),
    }
    params = {
        "aspect": rng.uniform(1.3, 1.75),
        "stand": float(rng.random() < 0.7),
        "on": float(rng.random() < 0.75),
        "tilt": rng.normal(0.0, 0.03),
        "flip": 1.0,
        "blocks": float(rng.integers(0, 5)),
        "block_seed": float(rng.integers(1 << 30)),
        "grad_dir": rng.uniform(0, 2 * np.pi),
    }
    return Style("tv", colors, params)


def _draw_tv(pt: Painter, st: Style, cx: float, cy: float, size: float) -> None:
    p, col = st.params, st.colors
    t = LocalFrame(cx, cy, size, p["tilt"], p["flip"])
    if p["stand"] > 0.5:
        y0, y1 = -0.5, 0.22
        pt.poly(
            t((-0.035, y1 - 0.01), (0.035, y1 - 0.01), (0.035, 0.44), (-0.035, 0.44)), col["stand"]
        )
        pt.poly(t((-0.22, 0.44), (0.22, 0.44), (0.26, 0.5), (-0.26, 0.5)), col["stand"])
    else:
        y0, y1 = -0.4, 0.4
    hw = (y1 - y0) * p["aspect"] / 2
    pt.poly(t((-hw, y0), (hw, y0), (hw, y1), (-hw, y1)), col["bezel"])
    b = 0.035
    screen = t((-hw + b, y0 + b), (hw - b, y0 + b), (hw - b, y1 - b), (-hw + b, y1 - b))
    if p["on"] > 0.5:
        sub = Painter(pt.x0, pt.y0, pt.mask.shape[1], pt.mask.shape[0])
        sub.poly(screen, col["screen_a"])
        sub.shade_linear(np.array([cx, cy]), p["grad_dir"], size / 2, 0.5)
        brng = np.random.default_rng(int(p["block_seed"]))
        for _ in range(int(p["blocks"])):
            u0, u1 = np.sort(brng.uniform(-hw + b, hw - b, 2))
            v0, v1 = np.sort(brng.uniform(y0 + b, y1 - b, 2))
            c = tuple(int(v) for v in brng.integers(0, 256, 3))
            sub.poly(t((u0, v0), (u1, v0), (u1, v1), (u0, v1)), c, mask=False)
        on = sub.mask > 0
        pt.rgb[on] = sub.rgb[on]
    else:
        pt.poly(screen, scale(col["bezel"], 1.6), mask=False)
        pt.line(t.p(-hw * 0.6, y0 + 0.1), t.p(-hw * 0.2, y1 - 0.1), t.s(0.08), (70, 72, 78))


_SAMPLERS: dict[str, Callable[[np.random.Generator], Style]] = {
    "person": sample_person,
    "dog": _sample_dog,
    "sports ball": _sample_ball,
    "bottle": _sample_bottle,
    "chair": _sample_chair,
    "tv": _sample_tv,
}
_DRAWERS: dict[str, Callable[[Painter, Style, float, float, float], None]] = {
    "person": draw_person,
    "dog": _draw_dog,
    "sports ball": _draw_ball,
    "bottle": _draw_bottle,
    "chair": _draw_chair,
    "tv": _draw_tv,
}
assert set(_SAMPLERS) == set(_DRAWERS) == set(BY_NAME)


def sample_style(category: str, rng: np.random.Generator) -> Style:
    """Random shape, pose and colours for one object of ``category`` (a COCO-like name)."""
    return _SAMPLERS[category](rng)


def draw(
    style: Style, cx: float, cy: float, size: float, width: int, height: int
) -> Painter | None:
    """Paint ``style`` centred at frame pixel ``(cx, cy)``, ``size`` px tall.

    Returns a :class:`Painter` patch clipped to the ``width x height`` frame (``rgb``
    ``uint8 [h, w, 3]``, ``mask`` ``uint8 [h, w]`` 0/255), or ``None`` if the object is fully
    outside the frame or smaller than a pixel.
    """
    if size < 1.0:
        return None
    reach = PATCH_REACH * size + 2
    x0, y0 = max(int(np.floor(cx - reach)), 0), max(int(np.floor(cy - reach)), 0)
    x1, y1 = min(int(np.ceil(cx + reach)), width), min(int(np.ceil(cy + reach)), height)
    if x1 <= x0 or y1 <= y0:
        return None
    painter = Painter(x0, y0, x1 - x0, y1 - y0)
    _DRAWERS[style.category](painter, style, cx, cy, size)
    return painter
