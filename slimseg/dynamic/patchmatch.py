"""Vectorised multi-source PatchMatch (Barnes et al. 2009) for filling removed regions.

The nearest-neighbour field (NNF) maps every *hole* pixel ``p`` of the target to a source pixel
``(r, q)`` of one of ``R`` source images that are already roughly aligned with the target (the
reference frames warped by a homography, see ``restore.py``). The hole is filled by copying
``source[r, q]`` (RGB and, through the same field, depth).

- **Patch distance** between the patch around ``p`` and the one around ``q``: mean squared
  colour difference over 13 samples of the ``k × k`` patch (a 3 × 3 grid spanning it plus the
  centre's 4-neighbourhood; sparse sampling keeps the vectorised gathers affordable at 640 ×
  480) that are usable on *both* sides. Source pixels are usable where ``valid[r]`` (inside
  the warped frame and not removed in their own frame); a source centre that is not valid is
  never chosen. Target pixels weigh 1 where known (outside the hole), ``HOLE_WEIGHT`` where
  already filled (see below) and 0 where still empty: the removed content itself is never
  compared. A patch whose usable samples cover only part of its weight pays
  ``COVER_PENALTY × (1 - coverage)``.
- **Initialisation** (coarsest level): the identity ``q = p`` in the first source valid there
  (the homography warp is a good prior), random valid pixels where none is. Finer levels start
  from the doubled field of their parent pixel.
- **Propagation, from the border inwards.** A pixel deep inside a large hole has no known
  pixel in its patch, and comparing it with its own current fill is a trap: any coherent field
  matches its own copy exactly, so nothing would ever improve. Each level therefore first
  solves the hole ring by ring (chessboard distance to the known pixels, vectorised over all
  pixels of a ring): a ring-``d`` pixel tries the shifted matches of its 8 neighbours in rings
  ``< d``, then of its 4 neighbours in ring ``d`` (along the ring), with random search after
  each round, and the ring is filled before the next one. Matches found at the border, where
  known pixels anchor them, thus grow coherently inwards.
- **Sweeps** (coarse levels only; the two finest inherit a good field): ``iters`` jump-flood
  passes over the whole hole, each pixel trying the shifted matches of its neighbours at
  distance 4, 2, 1, from left/top on even passes and right/bottom on odd ones (the
  alternating scan orders of the original), then random search.
- **Random search**: candidates ``q + U[-R, R]²`` with ``R`` halving from ``search_radius`` to
  1, plus one candidate in a random other source at the same position.
- **Coarse to fine**: a pyramid (2× area downsampling; a coarse pixel is in the hole when any
  of its fine pixels is, valid when at least half of them are), by default deep enough that
  every hole pixel of the coarsest level has known pixels within its patch.

Everything is numpy over arrays of hole pixels; there is no per-pixel Python loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

HOLE_WEIGHT = 0.5  # weight of already-filled hole pixels in the patch distance
COVER_PENALTY = 0.05  # in squared [0, 1] colour units
INVALID = np.float32(1e9)


@dataclass
class NNField:
    """Result of :func:`patchmatch`: filled ``image float32 [H, W, C]``; per pixel the chosen
    source ``ref int32 [H, W]`` (-1 outside the hole) and position ``qy, qx int32 [H, W]``;
    ``cost float32 [H, W]`` patch distance (0 outside the hole)."""

    image: np.ndarray
    ref: np.ndarray
    qy: np.ndarray
    qx: np.ndarray
    cost: np.ndarray

    def gather(self, sources: np.ndarray, fill: np.ndarray) -> np.ndarray:
        """Copy ``sources [R, H, W, ...]`` through the field into ``fill [H, W, ...]`` (a copy)."""
        out = fill.copy()
        hole = self.ref >= 0
        out[hole] = sources[self.ref[hole], self.qy[hole], self.qx[hole]]
        return out


def patchmatch(
    target: np.ndarray,
    hole: np.ndarray,
    sources: np.ndarray,
    valid: np.ndarray,
    patch: int = 7,
    iters: int = 4,
    levels: int | None = None,
    search_radius: int = 4,
    seed: int = 0,
) -> NNField:
    """Fill ``hole bool [H, W]`` of ``target float32 [H, W, C]`` (values in [0, 1]) from
    ``sources float32 [R, H, W, C]`` usable where ``valid bool [R, H, W]``.

    ``patch`` odd patch side, ``iters`` sweeps per level (none on the two finest levels),
    ``levels`` pyramid levels (None: until the hole is at most ``patch // 2`` px from known
    pixels, while the min side stays >= ``4 * patch``), ``search_radius`` px random-search
    radius on every level. Deterministic for a given ``seed``.
    """
    target = np.asarray(target, np.float32)
    if target.ndim == 2:
        target = target[..., None]
    sources = np.asarray(sources, np.float32)
    if sources.ndim == 3:
        sources = sources[..., None]
    hole = np.asarray(hole, bool)
    valid = np.asarray(valid, bool)
    h, w, c = target.shape
    if hole.shape != (h, w) or sources.shape[1:] != (h, w, c) or valid.shape != sources.shape[:3]:
        raise ValueError(
            f"patchmatch: target {target.shape}, hole {hole.shape}, sources {sources.shape}, "
            f"valid {valid.shape} do not agree (want [H,W,C], [H,W], [R,H,W,C], [R,H,W])"
        )
    if patch < 1 or patch % 2 == 0:
        raise ValueError(f"patchmatch: patch must be an odd size >= 1, got {patch}")
    if len(sources) == 0 or not valid.any():
        raise ValueError("patchmatch: no valid source pixel to copy from")
    rng = np.random.default_rng(seed)
    pyramid = [(target, hole, sources, valid)]
    while levels is None or len(pyramid) < levels:
        t, hl, s, v = pyramid[-1]
        if min(t.shape[:2]) < 4 * patch:
            break
        if levels is None and _depth(hl) <= patch // 2:
            break
        pyramid.append(_down(t, hl, s, v))
    field: NNField | None = None
    for lvl in range(len(pyramid) - 1, -1, -1):
        t, hl, s, v = pyramid[lvl]
        n_it = iters if lvl >= 2 or len(pyramid) == 1 else 0
        field = _solve(t, hl, s, v, field, patch, n_it, search_radius, rng)
    assert field is not None
    return field


def _depth(hole: np.ndarray) -> float:
    """Largest distance (px) from a hole pixel to the nearest known pixel."""
    if not hole.any():
        return 0.0
    if hole.all():
        return float(max(hole.shape))
    return float(cv2.distanceTransform(hole.astype(np.uint8), cv2.DIST_C, 3).max())


def _down(t: np.ndarray, hl: np.ndarray, s: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, ...]:
    """2× area downsampling; the hole grows (any), validity needs half of the fine pixels."""
    h2, w2 = t.shape[0] // 2, t.shape[1] // 2

    known = (~hl).astype(np.float32)[: 2 * h2, : 2 * w2]
    kt = known.reshape(h2, 2, w2, 2).sum((1, 3))
    tt = (t[: 2 * h2, : 2 * w2] * known[..., None]).reshape(h2, 2, w2, 2, -1).sum((1, 3))
    t2 = tt / np.maximum(kt, 1)[..., None]
    hl2 = hl[: 2 * h2, : 2 * w2].reshape(h2, 2, w2, 2).any((1, 3))
    vf = v[:, : 2 * h2, : 2 * w2].astype(np.float32)
    vs = vf.reshape(len(v), h2, 2, w2, 2).sum((2, 4))
    ss = (s[:, : 2 * h2, : 2 * w2] * vf[..., None]).reshape(len(s), h2, 2, w2, 2, -1).sum((2, 4))
    s2 = ss / np.maximum(vs, 1)[..., None]
    return t2.astype(np.float32), hl2, s2.astype(np.float32), vs >= 2


class _Level:
    """Padded sources of one pyramid level and the patch distance against them."""

    def __init__(self, s: np.ndarray, v: np.ndarray, hl: np.ndarray, patch: int) -> None:
        self.h, self.w, self.c = s.shape[1:]
        self.r = r = patch // 2
        self.hp, self.wp = self.h + 2 * r, self.w + 2 * r
        self.src = np.pad(s, ((0, 0), (r, r), (r, r), (0, 0)), mode="edge").reshape(-1, self.c)
        self.valid = np.pad(v, ((0, 0), (r, r), (r, r))).reshape(-1)
        self.v = v
        dy, dx = _pattern(r)
        self.doff = dy * self.wp + dx  # [K] flat offsets in the padded grid
        self.py, self.px = np.nonzero(hl)

    def set_target(self, est: np.ndarray, weight: np.ndarray) -> None:
        """The target image ``[H, W, C]`` and its per-pixel weights ``[H, W]``."""
        r = self.r
        self.timg = np.pad(est, ((r, r), (r, r), (0, 0)), mode="edge").reshape(-1, self.c)
        self.tweight = np.pad(weight, ((r, r), (r, r))).reshape(-1)
        self.tpos = (self.py + r) * self.wp + (self.px + r)  # hole pixels in the padded grid

    def update(self, sel: np.ndarray, values: np.ndarray, weight: float) -> None:
        """Write filled ``values [S, C]`` of hole pixels ``sel`` into the target."""
        self.timg[self.tpos[sel]] = values
        self.tweight[self.tpos[sel]] = weight

    def target(self, sel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Target patches ``[S, K, C]`` and weights ``[S, K]`` around hole pixels ``sel``."""
        idx = self.tpos[sel][:, None] + self.doff[None]
        return self.timg[idx], self.tweight[idx]

    def cost(
        self, tpatch: np.ndarray, tw: np.ndarray, ref: np.ndarray, qy: np.ndarray, qx: np.ndarray
    ) -> np.ndarray:
        """Patch distance of target patches to source ``ref`` at ``(qy, qx)`` → ``[S]``."""
        r = self.r
        qy = np.clip(qy, 0, self.h - 1)
        qx = np.clip(qx, 0, self.w - 1)
        centre = ref * (self.hp * self.wp) + (qy + r) * self.wp + (qx + r)
        idx = centre[:, None] + self.doff[None]
        w = tw * self.valid[idx]
        diff = ((self.src[idx] - tpatch) ** 2).sum(2)
        den = w.sum(1)
        d = (w * diff).sum(1) / np.maximum(den, 1e-6)
        d += COVER_PENALTY * (1.0 - den / np.maximum(tw.sum(1), 1e-6))
        d[~self.valid[centre]] = INVALID
        return d.astype(np.float32)

    def copy(self, ref: np.ndarray, qy: np.ndarray, qx: np.ndarray) -> np.ndarray:
        """Source values ``[S, C]`` at the matches."""
        r = self.r
        return self.src[ref * (self.hp * self.wp) + (qy + r) * self.wp + (qx + r)]


def _pattern(r: int) -> tuple[np.ndarray, np.ndarray]:
    """Sparse patch samples within radius ``r``: a 3 × 3 grid spanning the patch plus the
    4-neighbourhood of the centre (13 samples for r >= 2; the full square for r <= 1)."""
    if r <= 1:
        dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
        return dy.ravel(), dx.ravel()
    pts = {(a, b) for a in (-r, 0, r) for b in (-r, 0, r)} | {(1, 0), (-1, 0), (0, 1), (0, -1)}
    arr = np.array(sorted(pts))
    return arr[:, 0], arr[:, 1]


_NEIGHBOURS = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx]


def _solve(
    t: np.ndarray,
    hl: np.ndarray,
    s: np.ndarray,
    v: np.ndarray,
    parent: NNField | None,
    patch: int,
    iters: int,
    radius: int,
    rng: np.random.Generator,
) -> NNField:
    """One level: onion-peel pass from the hole border inwards, then ``iters`` sweeps."""
    lv = _Level(s, v, hl, patch)
    h, w = hl.shape
    py, px = lv.py, lv.px
    n = len(py)
    if n == 0:
        z = np.zeros((h, w), np.int32)
        return NNField(t.copy(), z - 1, z, z.copy(), np.zeros((h, w), np.float32))
    ref, qy, qx = _initial(lv, parent, rng)
    cost = np.full(n, INVALID, np.float32)
    ring = cv2.distanceTransform(hl.astype(np.uint8), cv2.DIST_C, 3).astype(np.int64)[py, px]
    pos = np.full((h, w), -1, np.int64)
    pos[py, px] = np.arange(n)
    lv.set_target(t, np.where(hl, np.float32(0.0), np.float32(1.0)))
    ring_rounds = 2

    def improve(sel: np.ndarray, tp: np.ndarray, tw: np.ndarray, cr, cy, cx, ok=None) -> None:
        """Keep the candidates ``(cr, cy, cx)`` that beat the current matches of ``sel``."""
        cy = np.clip(cy, 0, h - 1)
        cx = np.clip(cx, 0, w - 1)
        new = (cr != ref[sel]) | (cy != qy[sel]) | (cx != qx[sel])  # skip repeated candidates
        if ok is not None:
            new &= ok
        k = np.flatnonzero(new)
        if len(k) == 0:
            return
        c = lv.cost(tp[k], tw[k], cr[k], cy[k], cx[k])
        better = c < cost[sel[k]]
        k = k[better]
        b = sel[k]
        ref[b], qy[b], qx[b], cost[b] = cr[k], cy[k], cx[k], c[better]

    def search(sel: np.ndarray, tp: np.ndarray, tw: np.ndarray) -> None:
        rad = radius
        while rad >= 1:
            jy = rng.integers(-rad, rad + 1, len(sel))
            jx = rng.integers(-rad, rad + 1, len(sel))
            improve(sel, tp, tw, ref[sel].copy(), qy[sel] + jy, qx[sel] + jx)
            rad //= 2
        if len(lv.v) > 1:
            other = (ref[sel] + rng.integers(1, len(lv.v), len(sel))) % len(lv.v)
            improve(sel, tp, tw, other, py[sel], px[sel])

    # onion peel: ring d only sees known pixels and rings < d, so offsets grow coherently inwards
    for d in range(1, int(ring.max()) + 1):
        sel = np.flatnonzero(ring == d)
        if len(sel) == 0:
            continue
        tp, tw = lv.target(sel)
        cost[sel] = lv.cost(tp, tw, ref[sel], qy[sel], qx[sel])
        for rnd in range(ring_rounds):  # round 0: from outer rings; then along the ring too
            for dy, dx in _NEIGHBOURS if rnd == 0 else _NEIGHBOURS[1::2]:
                ny, nx = py[sel] + dy, px[sel] + dx
                inside = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
                nb = np.where(inside, pos[ny.clip(0, h - 1), nx.clip(0, w - 1)], -1)
                nbi = np.maximum(nb, 0)
                ok = (nb >= 0) & ((ring[nbi] < d) if rnd == 0 else (ring[nbi] <= d))
                improve(sel, tp, tw, ref[nbi], qy[nbi] - dy, qx[nbi] - dx, ok)
            search(sel, tp, tw)
        lv.update(sel, lv.copy(ref[sel], qy[sel], qx[sel]), HOLE_WEIGHT)
    # jump-flood sweeps over the whole hole, alternating directions
    every = np.arange(n)
    for it in range(iters):
        tp, tw = lv.target(every)
        cost = lv.cost(tp, tw, ref, qy, qx)
        sign = 1 if it % 2 == 0 else -1
        for step in (4, 2, 1):
            for dy, dx in ((0, -sign * step), (-sign * step, 0)):
                ny, nx = py + dy, px + dx
                inside = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
                nb = np.where(inside, pos[ny.clip(0, h - 1), nx.clip(0, w - 1)], -1)
                nbi = np.maximum(nb, 0)
                improve(every, tp, tw, ref[nbi], qy[nbi] - dy, qx[nbi] - dx, nb >= 0)
        search(every, tp, tw)
        lv.update(every, lv.copy(ref, qy, qx), HOLE_WEIGHT)
    img = t.copy()
    img[py, px] = lv.copy(ref, qy, qx)
    ref_m = np.full((h, w), -1, np.int32)
    qy_m = np.zeros((h, w), np.int32)
    qx_m = np.zeros((h, w), np.int32)
    cost_m = np.zeros((h, w), np.float32)
    ref_m[py, px], qy_m[py, px], qx_m[py, px], cost_m[py, px] = ref, qy, qx, cost
    return NNField(img, ref_m, qy_m, qx_m, cost_m)


def _initial(
    lv: _Level, parent: NNField | None, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Identity in the first valid source (or the parent's doubled match), random elsewhere."""
    py, px = lv.py, lv.px
    h, w = lv.h, lv.w
    ref = np.full(len(py), -1, np.int64)
    qy, qx = py.copy(), px.copy()
    if parent is not None:
        ph, pw = parent.ref.shape
        gy, gx = np.minimum(py // 2, ph - 1), np.minimum(px // 2, pw - 1)
        pr = parent.ref[gy, gx]
        cy = np.clip(2 * parent.qy[gy, gx] + (py - 2 * gy), 0, h - 1)
        cx = np.clip(2 * parent.qx[gy, gx] + (px - 2 * gx), 0, w - 1)
        ok = (pr >= 0) & lv.v[np.maximum(pr, 0), cy, cx]
        ref[ok], qy[ok], qx[ok] = pr[ok], cy[ok], cx[ok]
    for r in range(len(lv.v)):
        free = (ref < 0) & lv.v[r, py, px]
        ref[free], qy[free], qx[free] = r, py[free], px[free]
    rest = ref < 0
    if rest.any():
        vr, vy, vx = np.nonzero(lv.v)
        pick = rng.integers(0, len(vr), int(rest.sum()))
        ref[rest], qy[rest], qx[rest] = vr[pick], vy[pick], vx[pick]
    return ref, qy.astype(np.int64), qx.astype(np.int64)
