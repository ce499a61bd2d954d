"""YOLO-SLAM depth-RANSAC (docs/papers.md §4): which keypoints in a person box are dynamic.

Inside a detection box the keypoints are a mix of points on the person and points on the
background seen around them. Depth-RANSAC repeatedly draws 2 points with valid depth, collects
every other point whose inclusion keeps the depth variance below ``threshold`` and keeps the
largest such set: those points lie on the (dominant, depth-coherent) person and are dynamic;
the rest of the box stays static.

Units and definitions: depths are metres; 0 or NaN (or any non-finite or negative value) marks
an invalid depth. "Variance" is the **population** variance of a set of depths,
``mean((d - mean(d)) ** 2)`` in m² (``np.var`` with ``ddof=0``); the paper's nThre = 0.43 m² is
used on TUM depth in metres.

Two growth rules are offered (``mode``):

- ``"pair"`` (default): a candidate joins when the variance of {seed pair + candidate} is at
  most ``threshold``. With coincident seeds this admits points within ``sqrt(4.5 * threshold)``
  (≈ 1.39 m at 0.43) of the seed mean, independently of how many points are already in.
- ``"grow"``: candidates are sorted by ``|d - seed mean|`` and the set grows along that order
  while the running population variance of the whole set stays at most ``threshold``. This is
  the literal "keep the set's variance below nThre" reading, but a set variance is insensitive
  to a few far points: 60 points at 2 m absorb up to 8 points at 4 m before the variance of the
  set exceeds 0.43 m², so background points at the box edge end up dynamic.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

DEFAULT_THRESHOLD = 0.43  # m², YOLO-SLAM's nThre on TUM depth in metres
_W_EPS = 1e-6  # inlier-ratio clamp for the adaptive iteration count

Mode = Literal["pair", "grow"]


def valid_depth(depths: np.ndarray) -> np.ndarray:
    """``bool [N]``: finite and strictly positive depths."""
    d = np.asarray(depths, np.float64)
    with np.errstate(invalid="ignore"):
        return np.isfinite(d) & (d > 0)


def adaptive_iterations(inlier_ratio: float, confidence: float, sample_size: int) -> float:
    """RANSAC iteration count ``k = log(1 - P) / log(1 - w^N)``.

    ``w`` (``inlier_ratio``) is clamped to ``[1e-6, 1 - 1e-6]``; returns ``inf`` when ``w^N`` is
    too small to ever expect an all-inlier sample, and ``0`` when ``confidence <= 0``.
    """
    if confidence <= 0:
        return 0.0
    p = min(confidence, 1 - 1e-12)
    w = min(max(inlier_ratio, _W_EPS), 1 - _W_EPS)
    wn = w**sample_size
    denom = math.log1p(-wn)
    if denom == 0.0:
        return math.inf
    return math.log1p(-p) / denom


def _pair_inliers(d: np.ndarray, a: int, b: int, threshold: float) -> np.ndarray:
    """Mode "pair": ``bool [n]`` where var({d[a], d[b], d[i]}) <= threshold (seeds included).

    ``d [n]`` valid depths (m). For seeds with mean m and half-gap h, the 3-point population
    variance is ``2 h²/3 + 2 (d_i - m)²/9``.
    """
    m = 0.5 * (d[a] + d[b])
    h2 = (0.5 * (d[a] - d[b])) ** 2
    var3 = 2.0 * h2 / 3.0 + 2.0 * (d - m) ** 2 / 9.0
    keep = var3 <= threshold
    keep[[a, b]] = True
    return keep


def _grow_inliers(d: np.ndarray, a: int, b: int, threshold: float) -> np.ndarray:
    """Mode "grow": ``bool [n]``, the seeds plus the longest prefix of the others (sorted by
    distance to the seed mean) along which the running population variance stays <= threshold.

    ``d [n]`` valid depths (m). Sums are taken relative to the seed mean to limit cancellation.
    """
    n = len(d)
    m = 0.5 * (d[a] + d[b])
    rest = np.ones(n, bool)
    rest[[a, b]] = False
    idx = np.flatnonzero(rest)
    order = idx[np.argsort(np.abs(d[idx] - m), kind="stable")]
    x = np.concatenate(([d[a] - m, d[b] - m], d[order] - m))  # [n], seeds first
    count = np.arange(1, n + 1, dtype=np.float64)
    s1 = np.cumsum(x)
    s2 = np.cumsum(x * x)
    var = np.maximum(s2 / count - (s1 / count) ** 2, 0.0)  # [n] running population variance
    ok = var[1:] <= threshold  # prefixes of size 2..n
    size = n if ok.all() else 1 + int(np.argmin(ok))  # first failing prefix is excluded
    keep = np.zeros(n, bool)
    if size >= 2:
        keep[[a, b]] = True
        keep[order[: size - 2]] = True
    return keep


def depth_ransac(
    depths: np.ndarray,
    threshold: float = DEFAULT_THRESHOLD,
    confidence: float = 0.99,
    sample_size: int = 2,
    max_iterations: int = 200,
    rng: np.random.Generator | None = None,
    mode: Mode = "pair",
) -> np.ndarray:
    """Largest depth-coherent set of points (YOLO-SLAM Algorithm 1).

    ``depths [N]`` float metres, 0 / NaN / negative = invalid; ``threshold`` m² bounds the
    population variance of the set (see the module docstring for the ``mode`` growth rules).
    Each iteration draws 2 distinct valid points (a pair whose own variance exceeds
    ``threshold`` is rejected), grows its set and keeps the largest (first one on ties). The
    iteration count adapts as ``k = log(1 - confidence) / log(1 - w^sample_size)`` with ``w``
    the best inlier ratio so far, capped by ``max_iterations``; a set holding every valid
    point stops the search. ``rng`` defaults to ``np.random.default_rng(0)`` so that runs are
    reproducible.

    Returns ``bool [N]``: True for the largest set (dynamic: on the person), False for the
    other points and for invalid depths. With a single valid point, that point is the set (a
    one-point set has variance 0); with none, all False.
    """
    if mode not in ("pair", "grow"):
        raise ValueError(f"unknown depth-RANSAC mode {mode!r}; valid: ['pair', 'grow']")
    d_all = np.asarray(depths, np.float64).reshape(-1)
    valid = valid_depth(d_all)
    out = np.zeros(d_all.shape[0], bool)
    vidx = np.flatnonzero(valid)
    n = len(vidx)
    if n == 0:
        return out
    if n == 1:
        out[vidx] = True
        return out
    rng = np.random.default_rng(0) if rng is None else rng
    d = d_all[vidx]
    grow = _pair_inliers if mode == "pair" else _grow_inliers
    best = np.zeros(n, bool)
    best_size = 0
    k = float(max_iterations)
    it = 0
    while it < min(k, max_iterations):
        it += 1
        a, b = (int(i) for i in rng.choice(n, size=2, replace=False))
        if (0.5 * (d[a] - d[b])) ** 2 > threshold:
            continue
        keep = grow(d, a, b, threshold)
        size = int(keep.sum())
        if size > best_size:
            best, best_size = keep, size
            if size == n:
                break
            k = adaptive_iterations(size / n, confidence, sample_size)
    out[vidx[best]] = True
    return out


def screen_box_keypoints(
    keypoints_xy: np.ndarray,
    depth_m: np.ndarray,
    boxes: np.ndarray,
    threshold: float = DEFAULT_THRESHOLD,
    rng: np.random.Generator | None = None,
    mode: Mode = "pair",
) -> np.ndarray:
    """Depth-RANSAC inside each box: which keypoints are dynamic.

    ``keypoints_xy [N, 2]`` float px (x, y); ``depth_m [H, W]`` float metres (0 / NaN =
    invalid), sampled at the nearest pixel (points off the image have invalid depth);
    ``boxes [M, 4]`` xyxy px, inclusive edges. For every box the keypoints inside it go through
    :func:`depth_ransac`; a keypoint is dynamic if any box marks it dynamic. Keypoints outside
    every box, or with invalid depth, are static. Returns ``bool [N]`` (True = dynamic).
    """
    kp = np.asarray(keypoints_xy, np.float64).reshape(-1, 2)
    bx = np.asarray(boxes, np.float64).reshape(-1, 4)
    depth = np.asarray(depth_m)
    dynamic = np.zeros(len(kp), bool)
    if len(kp) == 0 or len(bx) == 0:
        return dynamic
    if depth.ndim != 2:
        raise ValueError(f"depth_m must be [H, W], got shape {depth.shape}")
    rng = np.random.default_rng(0) if rng is None else rng
    h, w = depth.shape
    xi = np.round(kp[:, 0]).astype(np.int64)
    yi = np.round(kp[:, 1]).astype(np.int64)
    on_image = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    z = np.zeros(len(kp), np.float64)
    z[on_image] = depth[yi[on_image], xi[on_image]]
    x, y = kp[:, 0], kp[:, 1]
    inside = (
        (x[None] >= bx[:, 0:1])
        & (x[None] <= bx[:, 2:3])
        & (y[None] >= bx[:, 1:2])
        & (y[None] <= bx[:, 3:4])
    )  # [M, N]
    for row in inside:
        idx = np.flatnonzero(row)
        if len(idx) == 0:
            continue
        dynamic[idx] |= depth_ransac(z[idx], threshold=threshold, rng=rng, mode=mode)
    return dynamic
