"""Instance masks on the source frame from prototypes and coefficients, in numpy (no torch).

The rule of :mod:`slimseg.ops.masks` (its module docstring), step for step, computed only
on each detection's pixels:

1. ``prob = sigmoid(coeffs · proto)``, float32 ``[Hp, Wp]``;
2. bilinear upsampling to the ``H × W`` network input with half-pixel centres (``src = (dst
   + 0.5) · s − 0.5`` with ``s = float32(size_in / size_out)``, clamped at 0, taps ``i0 =
   floor(src)`` and ``i0 + 1`` clamped to the map, weight ``l = src − i0``; x first, then y:
   ``(a·(1−lx) + b·lx)·(1−ly) + (c·(1−lx) + d·lx)·ly``, float32 without fused
   multiply-adds, the arithmetic of torch's CPU kernels), on the box's pixels only (pixel
   centre in the box; 0 elsewhere);
3. on a frame the letterbox did not resize: ``mask = prob > 0.5`` minus the padding;
   otherwise the cropped probabilities of the letterbox content are resized to the frame by
   the same bilinear rule and ``mask = value > 0.5``.

Steps 2 and 3 give the torch path's numbers exactly; step 1 (numpy's own product loop, no
BLAS threads, and ``exp``) differs from torch's BLAS and vectorised ``exp`` by a rounding of
the last bit on some pixels, so a mask pixel can differ
only where its value lies within a few float32 steps of 0.5
(``tests/deploy/test_postprocess_numpy.py`` measures it; docs/runtime_api.md).
"""

from __future__ import annotations

import numpy as np

from slimseg.ops.letterbox import LetterboxParams

F32 = np.float32


def pixel_span(lo: np.ndarray, hi: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """First pixel and pixel count ``int64 [N]`` whose centres ``x + 0.5`` lie in ``[lo, hi)``
    (float32 ``[N]``), within ``0..size-1`` (``docs/conventions.md`` §1)."""
    first = np.clip(np.ceil(lo - F32(0.5)), 0, size)
    end = np.clip(np.ceil(hi - F32(0.5)), 0, size)
    return first.astype(np.int64), np.maximum(end - first, 0).astype(np.int64)


def bilinear_taps(
    first: int, count: int, size_out: int, size_in: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Output pixels ``first .. first+count-1`` of a half-pixel-centre bilinear resize
    ``size_in → size_out`` along one axis: taps ``i0, i1 int64 [count]`` and weights ``w0, w1
    float32 [count]`` (``w0 = 1 − w1``)."""
    o = np.arange(first, first + count, dtype=F32)
    src = np.maximum((o + F32(0.5)) * F32(size_in / size_out) - F32(0.5), F32(0))
    i0 = np.minimum(np.floor(src), size_in - 1).astype(np.int64)
    i1 = np.minimum(i0 + 1, size_in - 1)
    w1 = np.clip(src - i0.astype(F32), F32(0), F32(1))
    return i0, i1, F32(1) - w1, w1


def resample(
    grid: np.ndarray, ys: tuple[np.ndarray, ...], xs: tuple[np.ndarray, ...]
) -> np.ndarray:
    """``grid float32 [Hs, Ws]`` at the taps of :func:`bilinear_taps` for rows ``ys`` and
    columns ``xs`` → ``float32 [len(ys[0]), len(xs[0])]`` (x first, then y)."""
    iy0, iy1, wy0, wy1 = ys
    ix0, ix1, wx0, wx1 = xs
    r0, r1 = grid[iy0], grid[iy1]
    t0 = r0[:, ix0] * wx0 + r0[:, ix1] * wx1
    t1 = r1[:, ix0] * wx0 + r1[:, ix1] * wx1
    return t0 * wy0[:, None] + t1 * wy1[:, None]


def sigmoid(x: np.ndarray) -> np.ndarray:
    """``1 / (1 + exp(−x))`` in float32 (``exp`` overflows to inf for very negative x: 0)."""
    with np.errstate(over="ignore"):
        return F32(1) / (F32(1) + np.exp(-x))


def frame_masks(
    coeffs: np.ndarray,
    proto: np.ndarray,
    boxes: np.ndarray,
    p: LetterboxParams,
    frame_hw: tuple[int, int],
    threshold: float | None = 0.5,
) -> np.ndarray:
    """``bool [N, h, w]`` masks on the source frame ``frame_hw`` of ``N`` detections:
    ``coeffs float32 [N, nm]``, the image's ``proto float32 [nm, Hp, Wp]``, ``boxes float32
    [N, 4]`` xyxy in network-input pixels, ``p`` the frame's letterbox (module docstring).
    ``threshold=None``: the values a mask thresholds (``float32 [N, h, w]``, 0 where no tap
    reaches the box), to see how close a pixel is to flipping."""
    if coeffs.ndim != 2 or proto.ndim != 3 or coeffs.shape[1] != proto.shape[0]:
        raise ValueError(
            f"expected coeffs [N, nm] and proto [nm, Hp, Wp], got {coeffs.shape} and {proto.shape}"
        )
    nm, hp, wp = proto.shape
    # einsum's own loop, not BLAS: OpenBLAS would start a thread per core for this product
    # (10x slower than one thread beside a busy SLAM loop on 2 cores) and ignore `threads`
    flat = proto.reshape(nm, hp * wp).astype(F32)
    probs = sigmoid(np.einsum("nk,kp->np", coeffs.astype(F32), flat, optimize=False))
    return masks_from_probs(probs.reshape(-1, hp, wp), boxes, p, frame_hw, threshold)


def masks_from_probs(
    probs: np.ndarray,
    boxes: np.ndarray,
    p: LetterboxParams,
    frame_hw: tuple[int, int],
    threshold: float | None = 0.5,
) -> np.ndarray:
    """Steps 2 and 3 of the module docstring: ``probs float32 [N, Hp, Wp]`` (sigmoid of the
    mask terms at prototype resolution, e.g. an end-to-end export's ``masks``) and ``boxes
    float32 [N, 4]`` xyxy in network-input pixels → ``bool [N, h, w]`` on the frame (``float32``
    values with ``threshold=None``), as :func:`frame_masks`."""
    n, (h, w) = len(probs), frame_hw
    out = np.zeros((n, h, w), bool if threshold is not None else F32)
    if n == 0:
        return out
    hp, wp = probs.shape[1:]
    probs = np.asarray(probs, F32)
    b = boxes.astype(F32)
    x0, nx = pixel_span(b[:, 0], b[:, 2], p.out_w)
    y0, ny = pixel_span(b[:, 1], b[:, 3], p.out_h)
    same = (p.new_h, p.new_w) == (h, w)
    fx, fnx = _frame_span(x0, nx, p.left, p.new_w, w)
    fy, fny = _frame_span(y0, ny, p.top, p.new_h, h)
    for d in range(n):
        if nx[d] == 0 or ny[d] == 0:
            continue
        ys = bilinear_taps(int(y0[d]), int(ny[d]), p.out_h, hp)
        xs = bilinear_taps(int(x0[d]), int(nx[d]), p.out_w, wp)
        values = resample(probs[d].reshape(hp, wp), ys, xs)  # [ny, nx] at the input
        if same:  # no resize: threshold, then drop the padding
            top, left = int(y0[d]) - p.top, int(x0[d]) - p.left
            r0, c0 = max(top, 0), max(left, 0)
            r1, c1 = min(top + int(ny[d]), h), min(left + int(nx[d]), w)
            if r1 > r0 and c1 > c0:
                kept = values[r0 - top : r1 - top, c0 - left : c1 - left]
                out[d, r0:r1, c0:c1] = kept if threshold is None else kept > threshold
            continue
        if fnx[d] == 0 or fny[d] == 0:
            continue
        # the content map is 0 outside the box: a window of the box's values with a zero
        # border, every tap outside the box clamped onto that border
        local = np.zeros((int(ny[d]) + 2, int(nx[d]) + 2), F32)
        local[1:-1, 1:-1] = values
        fys = _onto_window(bilinear_taps(int(fy[d]), int(fny[d]), h, p.new_h), y0[d] - p.top, ny[d])
        fxs = _onto_window(
            bilinear_taps(int(fx[d]), int(fnx[d]), w, p.new_w), x0[d] - p.left, nx[d]
        )
        r, c = int(fy[d]), int(fx[d])
        at_frame = resample(local, fys, fxs)
        window = out[d, r : r + int(fny[d]), c : c + int(fnx[d])]
        window[...] = at_frame if threshold is None else at_frame > threshold
    return out


def _onto_window(
    taps: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], origin: int, count: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Taps on the letterbox content → indices into a window of ``count`` pixels starting at
    content pixel ``origin``, with a zero border of one pixel (taps outside → the border)."""
    i0, i1, w0, w1 = taps
    return np.clip(i0 - origin + 1, 0, count + 1), np.clip(i1 - origin + 1, 0, count + 1), w0, w1


def _frame_span(
    first: np.ndarray, count: np.ndarray, offset: int, new: int, dst: int
) -> tuple[np.ndarray, np.ndarray]:
    """Along one axis, the first frame pixel and pixel count ``[N]`` whose bilinear taps can
    reach the content pixels of each detection's input span ``first, count`` (``offset``: the
    padding before the ``new`` content pixels; ``dst``: the frame's size); one pixel of margin."""
    c0 = np.clip(first - offset, 0, new).astype(F32)
    c1 = np.clip(first + count - offset, 0, new).astype(F32)
    scale = F32(dst / new)
    f0 = np.clip(np.ceil((c0 - F32(0.5)) * scale - F32(0.5)) - 1, 0, dst)
    f1 = np.clip(np.ceil((c1 + F32(0.5)) * scale - F32(0.5)) + 1, 0, dst)
    f1 = np.where(c1 > c0, f1, f0)
    return f0.astype(np.int64), (f1 - f0).astype(np.int64)
