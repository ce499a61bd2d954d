"""Instance masks from prototype masks and per-detection coefficients, and back to the frame.

The exact rule, which a C++ runtime follows step by step to get the same pixels
(``H × W`` network input, ``Hp × Wp`` prototypes, ``H/4 × W/4``, or ``H/2 × W/2`` for the
``-hr`` variants):

:func:`assemble_masks` (per detection, boxes xyxy in input pixels):

1. ``prob = sigmoid(coeffs · proto)``: a ``[Hp, Wp]`` map, float32 (also under autocast);
2. bilinear upsampling to ``H × W`` with half-pixel centres: ``src = (dst + 0.5) · Hp / H −
   0.5``, clamped at the borders (``torch`` ``align_corners=False``; ``cv2.resize`` with
   ``INTER_LINEAR`` on float32 does the same);
3. crop: pixel ``(y, x)`` is kept if its centre is in the box, ``x1 <= x + 0.5 < x2`` and
   ``y1 <= y + 0.5 < y2``, else set to 0;
4. ``mask = prob > 0.5``.

No crop at prototype resolution by default: with the crop of step 3 it could only change
pixels *inside* the box, by mixing a zeroed outside cell into their bilinear interpolation
(pure erosion: e.g. the corner pixels of every box aligned to the prototype grid are lost
even where the prototypes are certain). ``proto_crop=True`` adds it, between steps 1 and 2,
for parity with runtimes that do it: the box scaled by ``(Wp / W, Hp / H)``; proto pixel
``(i, j)`` (covering ``[j, j+1) × [i, i+1)``) is kept if it overlaps the scaled box at all,
``j + 1 > x1p and j < x2p`` (same for rows), else set to 0.

:func:`masks_to_frame` (input-resolution masks or probabilities → ``h × w`` source frame,
:class:`~slimseg.ops.letterbox.LetterboxParams` ``p``):

1. take rows ``top : top + new_h`` and columns ``left : left + new_w`` (drop the padding);
2. as float32 (``True`` → 1.0), bilinear resize ``new_h × new_w → h × w`` with half-pixel
   centres and no antialiasing (as in step 2 above; skipped when the sizes are equal);
3. ``mask = value > 0.5``.

This is the exact inverse of the image letterbox (which resizes ``h × w → new_h × new_w``),
so masks land on the frame without the 1–12 px shifts seen in runtimes that round the
padding differently. Resizing probabilities (``assemble_masks(..., threshold=None)``) instead
of binary masks gives smoother edges when the frame is larger than the input.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
import torch.nn.functional as F

from slimseg.ops.letterbox import LetterboxParams
from slimseg.utils.full_precision import full_precision

CHUNK_AREA_RATIO = 0.5  # a window under this share of its chunk's first starts a new chunk


def _proto_window(boxes: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """``bool [N, h, w]``: proto pixels whose unit square overlaps xyxy ``boxes [N, 4]``
    (given in proto pixels)."""
    cols = torch.arange(w, device=boxes.device, dtype=boxes.dtype)
    rows = torch.arange(h, device=boxes.device, dtype=boxes.dtype)
    x1, y1, x2, y2 = (boxes[:, k, None] for k in range(4))
    in_x = (cols + 1 > x1) & (cols < x2)
    in_y = (rows + 1 > y1) & (rows < y2)
    return in_y[:, :, None] & in_x[:, None, :]


def _pixel_span(lo: torch.Tensor, hi: torch.Tensor, size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """First output pixel and pixel count ``[N]`` whose centres ``x + 0.5`` lie in
    ``[lo, hi)``, within ``0..size-1``."""
    first = torch.ceil(lo - 0.5).clamp(0, size)
    end = torch.ceil(hi - 0.5).clamp(0, size)
    return first.long(), (end - first).clamp(min=0).long()


def _bilinear_taps(
    first: torch.Tensor, count: torch.Tensor, span: int, size_out: int, size_in: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Along one axis, a window of ``span`` output pixels per detection covering its pixels
    ``first .. first+count-1`` (``span >= count``; the window is shifted left where it would
    leave ``0..size_out-1``, so its pixels are distinct real pixels): their indices
    ``[N, span]``, whether each is one of the detection's pixels, the two source taps and the
    weight of the second, for half-pixel-centre bilinear resizing ``size_in → size_out``."""
    start = torch.minimum(first, torch.full_like(first, size_out - span))
    o = start[:, None] + torch.arange(span, device=first.device)
    valid = (o >= first[:, None]) & (o < (first + count)[:, None])
    src = ((o.float() + 0.5) * (size_in / size_out) - 0.5).clamp(min=0)
    i0 = src.floor().long().clamp(max=size_in - 1)
    i1 = (i0 + 1).clamp(max=size_in - 1)
    return o, valid, i0, i1, (src - i0).clamp(0, 1)


def _resize_window(
    src: torch.Tensor,
    span_x: tuple[torch.Tensor, torch.Tensor],
    span_y: tuple[torch.Tensor, torch.Tensor],
    out_hw: tuple[int, int],
    threshold: float | None,
    src_hw: tuple[int, int] | None = None,
    origin: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Bilinear resize (half-pixel centres) of ``src [m, Hs, Ws]`` to ``out_hw``, computed only
    on a window around each detection's output span ``(first [m], count [m])`` per axis.

    Window-local source: with ``src_hw`` (the size of the map being resized) and ``origin``
    (row ``[m]``, column ``[m]`` of ``src[d, 1, 1]`` in that map), ``src`` holds only a window
    of each map with a border of one zero pixel, the map being 0 outside it.

    Returns ``values [m, sy, sx]`` (``bool`` thresholded at ``threshold``, or float when it is
    ``None``; 0 on window pixels outside the spans) and the window's top row and left column
    ``[m]`` in output pixels: window pixel ``(i, j)`` of detection ``d`` is output pixel
    ``(top[d] + i, left[d] + j)``, always inside ``out_hw``."""
    h, w = out_hw
    m, hs, ws = src.shape
    map_h, map_w = (hs, ws) if src_hw is None else src_hw
    sx, sy = int(span_x[1].max()), int(span_y[1].max())
    _, vx, ix0, ix1, lx = _bilinear_taps(*span_x, sx, w, map_w)
    _, vy, iy0, iy1, ly = _bilinear_taps(*span_y, sy, h, map_h)
    if origin is not None:  # map taps -> the local window; outside it -> its zero border
        oy, ox = origin[0][:, None] - 1, origin[1][:, None] - 1
        ix0, ix1 = ((ix0 - ox).clamp(0, ws - 1), (ix1 - ox).clamp(0, ws - 1))
        iy0, iy1 = ((iy0 - oy).clamp(0, hs - 1), (iy1 - oy).clamp(0, hs - 1))
    # x first, then y (the order of torch's and OpenCV's bilinear kernels).
    g0 = torch.gather(src, 2, ix0[:, None, :].expand(m, hs, sx))
    g1 = torch.gather(src, 2, ix1[:, None, :].expand(m, hs, sx))
    rows = g0 * (1 - lx)[:, None, :] + g1 * lx[:, None, :]  # [m, Hs, sx]
    g0 = torch.gather(rows, 1, iy0[:, :, None].expand(m, sy, sx))
    g1 = torch.gather(rows, 1, iy1[:, :, None].expand(m, sy, sx))
    local = g0 * (1 - ly)[:, :, None] + g1 * ly[:, :, None]  # [m, sy, sx]
    inside = vy[:, :, None] & vx[:, None, :]
    values = local * inside if threshold is None else (local > threshold) & inside
    # the windows' first pixels, as _bilinear_taps places them (also for empty windows)
    top = torch.minimum(span_y[0], torch.full_like(span_y[0], h - sy))
    left = torch.minimum(span_x[0], torch.full_like(span_x[0], w - sx))
    return values, top, left


def _integer_ratio(size_out: int, size_in: int) -> int | None:
    """``size_out / size_in`` when it is a power of two (1, 2, 4, ...), else ``None``: then
    every bilinear weight is a multiple of ``1 / (2 · ratio)``, exact in float32."""
    r, rem = divmod(size_out, size_in)
    return r if rem == 0 and r & (r - 1) == 0 else None


def _source_span(
    first: torch.Tensor, count: torch.Tensor, ratio: int, size_in: int
) -> tuple[torch.Tensor, int]:
    """Along one axis, the first source pixel ``[N]`` and the length (chunk maximum) of a
    source window whose ``ratio``-fold bilinear upsampling covers each detection's output
    pixels ``first .. first+count-1`` with every tap it needs: one source pixel of margin
    before (so the crop's own border clamp never reaches them) and the second tap of the last
    pixel after; shifted left where it would leave ``0..size_in-1``."""
    # source position of output pixel o: (o + 0.5) / r - 0.5 = (2o + 1 - r) / 2r
    last = first + count - 1
    i0_last = torch.div(2 * last + 1 - ratio, 2 * ratio, rounding_mode="floor").clamp(min=0)
    start = (torch.div(first, ratio, rounding_mode="floor") - 1).clamp(min=0)
    end = (i0_last + 2).clamp(max=size_in)
    need = torch.where(count > 0, end - start, torch.ones_like(start))
    span = int(need.max())
    return torch.minimum(start, torch.full_like(start, size_in - span)).clamp(min=0), span


def _upsample_window(
    src: torch.Tensor,
    span_x: tuple[torch.Tensor, torch.Tensor],
    span_y: tuple[torch.Tensor, torch.Tensor],
    ratio: int,
    threshold: float | None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`_resize_window` for an exact power-of-two upsampling ``ratio`` (output =
    ``ratio`` × the size of ``src [m, Hs, Ws]``): each detection's source window is cropped and
    upsampled by ``F.interpolate`` (bilinear, half-pixel centres). Its weights are multiples
    of ``1 / (2 · ratio)`` whatever the crop's offset, so the pixels equal those of upsampling
    the whole map, bit for bit. Same returns as :func:`_resize_window` (windows of
    ``ratio`` × the source window)."""
    m, hs, ws = src.shape
    x0, lx = _source_span(*span_x, ratio, ws)
    y0, ly = _source_span(*span_y, ratio, hs)
    rows = y0[:, None] + torch.arange(ly, device=src.device)
    cols = x0[:, None] + torch.arange(lx, device=src.device)
    flat = (rows[:, :, None] * ws + cols[:, None, :]).view(m, ly * lx)
    crop = torch.gather(src.reshape(m, hs * ws), 1, flat).view(m, ly, lx)
    up = F.interpolate(crop[:, None], size=(ratio * ly, ratio * lx), mode="bilinear")[:, 0]
    top, left = ratio * y0, ratio * x0
    oy = top[:, None] + torch.arange(ratio * ly, device=src.device)
    ox = left[:, None] + torch.arange(ratio * lx, device=src.device)
    in_y = (oy >= span_y[0][:, None]) & (oy < (span_y[0] + span_y[1])[:, None])
    in_x = (ox >= span_x[0][:, None]) & (ox < (span_x[0] + span_x[1])[:, None])
    if threshold is None:
        return up.mul_(in_y[:, :, None]).mul_(in_x[:, None, :]), top, left
    values = (up > threshold).view(torch.uint8)  # uint8 products: faster than bool ands
    values.mul_(in_y.view(torch.uint8)[:, :, None]).mul_(in_x.view(torch.uint8)[:, None, :])
    return values.view(torch.bool), top, left


def _size_chunks(
    order: torch.Tensor, nx: torch.Tensor, ny: torch.Tensor, chunk: int
) -> Iterator[torch.Tensor]:
    """Detections ``order [N]`` (by decreasing window area ``nx · ny``) in chunks of at most
    ``chunk`` whose windows are alike: a chunk ends before a detection whose area is under
    :data:`CHUNK_AREA_RATIO` of the chunk's first, since every detection of a chunk is computed
    on the chunk's largest window (one large person beside twenty small false positives would
    otherwise cost twenty large windows). Each pixel's value does not depend on the chunking."""
    area = (nx * ny)[order].tolist()
    start = 0
    for i in range(1, len(area) + 1):
        if i == len(area) or i - start >= chunk or area[i] < CHUNK_AREA_RATIO * area[start]:
            yield order[start:i]
            start = i


def _scatter_windows(
    out: torch.Tensor,
    k: torch.Tensor,
    values: torch.Tensor,
    top: torch.Tensor,
    left: torch.Tensor,
    out_hw: tuple[int, int],
) -> None:
    """Write windows ``values [m, sy, sx]`` at ``(top, left) [m]`` into rows ``k [m]`` of the
    contiguous ``out [N, H · W]`` (``out_hw = (H, W)``); the rest of ``out`` is untouched."""
    h, w = out_hw
    _, sy, sx = values.shape
    oy = top[:, None] + torch.arange(sy, device=top.device)
    ox = left[:, None] + torch.arange(sx, device=left.device)
    lin = (k[:, None, None] * h + oy[:, :, None]) * w + ox[:, None, :]
    out.view(-1).scatter_(0, lin.view(-1), values.reshape(-1))


def mask_windows(
    coeffs: torch.Tensor,
    proto: torch.Tensor,
    boxes: torch.Tensor,
    input_hw: tuple[int, int],
    threshold: float | None = 0.5,
    chunk: int = 32,
    proto_crop: bool = False,
) -> Iterator[tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]]:
    """:func:`assemble_masks` without the full-size output: per chunk of detections (sorted
    by box size), ``(k [m], values [m, sy, sx], top [m], left [m])``: the detections' indices,
    their masks on a window (``bool``, or probabilities when ``threshold`` is ``None``; 0
    outside the window) and the window's position in input pixels."""
    if coeffs.ndim != 2 or proto.ndim != 3 or coeffs.shape[1] != proto.shape[0]:
        raise ValueError(
            f"expected coeffs [N, nm] and proto [nm, Hp, Wp], got {tuple(coeffs.shape)} and "
            f"{tuple(proto.shape)}"
        )
    n = coeffs.shape[0]
    if boxes.shape != (n, 4):
        raise ValueError(f"expected boxes [{n}, 4], got {tuple(boxes.shape)}")
    if n == 0:
        return
    h, w = input_hw
    nm, hp, wp = proto.shape
    flat = proto.reshape(nm, hp * wp).float()
    b = boxes.detach().float()
    x0, nx = _pixel_span(b[:, 0], b[:, 2], w)
    y0, ny = _pixel_span(b[:, 1], b[:, 3], h)
    order = (nx * ny).argsort(descending=True)
    to_proto = torch.tensor([wp / w, hp / h, wp / w, hp / h], device=b.device)
    ratio = _integer_ratio(h, hp)
    if ratio != _integer_ratio(w, wp):
        ratio = None
    with full_precision(proto.device):  # float32 under autocast too (module docstring)
        # one product for all (a BLAS result may depend on the row count; chunks vary)
        probs = (coeffs.float() @ flat).sigmoid().view(n, hp, wp)
    for k in _size_chunks(order, nx, ny, chunk):
        with full_precision(proto.device):
            prob = probs[k]
            if proto_crop:
                prob = prob * _proto_window(b[k] * to_proto, hp, wp)
            spans = (x0[k], nx[k]), (y0[k], ny[k])
            if ratio is None:
                values, top, left = _resize_window(prob, *spans, (h, w), threshold)
            else:
                values, top, left = _upsample_window(prob, *spans, ratio, threshold)
        yield k, values, top, left


def assemble_masks(
    coeffs: torch.Tensor,
    proto: torch.Tensor,
    boxes: torch.Tensor,
    input_hw: tuple[int, int],
    threshold: float | None = 0.5,
    chunk: int = 32,
    proto_crop: bool = False,
) -> torch.Tensor:
    """Masks of ``N`` detections at network-input resolution.

    ``coeffs [N, nm]`` raw coefficients, ``proto [nm, Hp, Wp]`` prototypes of the image,
    ``boxes [N, 4]`` xyxy in input pixels, ``input_hw = (H, W)``. Returns ``bool [N, H, W]``
    (``prob > threshold``), or the cropped probabilities ``float32 [N, H, W]`` when
    ``threshold`` is ``None``. ``proto_crop`` also crops at prototype resolution (off by
    default, see the module docstring for why and for the exact steps).

    Only the pixels inside each box are interpolated (everything outside is 0 after the crop
    anyway): detections are sorted by box size and processed ``chunk`` at a time on a grid as
    large as the chunk's largest box, with vectorised gathers; the result equals full-frame
    ``F.interpolate`` followed by the crop (up to float rounding).
    """
    n, (h, w) = coeffs.shape[0], input_hw
    dtype = torch.float32 if threshold is None else torch.bool
    out = torch.zeros(n, h * w, dtype=dtype, device=coeffs.device)
    for k, values, top, left in mask_windows(
        coeffs, proto, boxes, input_hw, threshold, chunk, proto_crop
    ):
        _scatter_windows(out, k, values, top, left, (h, w))
    return out.view(n, h, w)


def masks_to_frame(
    masks: torch.Tensor,
    p: LetterboxParams,
    orig_hw: tuple[int, int],
    threshold: float = 0.5,
    chunk: int = 32,
    boxes: torch.Tensor | None = None,
) -> torch.Tensor:
    """``[N, H, W]`` masks (bool) or probabilities (float) at network-input resolution →
    ``bool [N, h, w]`` on the source frame ``orig_hw = (h, w)``.

    Removes the letterbox padding, resizes bilinearly to the frame and thresholds
    (``value > threshold``); see the module docstring for the exact steps. With ``boxes
    [N, 4]`` (xyxy input pixels; the masks must be 0 outside them, as
    :func:`assemble_masks` guarantees), only the frame pixels whose interpolation taps reach
    into a box are computed (same result, much faster for large frames).
    """
    if masks.ndim != 3 or tuple(masks.shape[1:]) != (p.out_h, p.out_w):
        raise ValueError(
            f"expected masks [N, {p.out_h}, {p.out_w}] (the letterbox output size), got "
            f"{tuple(masks.shape)}"
        )
    n = masks.shape[0]
    h, w = orig_hw
    content = masks[:, p.top : p.top + p.new_h, p.left : p.left + p.new_w]
    if (p.new_h, p.new_w) == (h, w):  # scale 1: only the padding to remove
        if content.dtype == torch.bool and 0 <= threshold < 1:
            return content.clone()
        return content.float() > threshold
    if boxes is None:
        out = []
        for s in range(0, n, chunk):
            m = content[s : s + chunk, None].float()
            m = F.interpolate(m, size=(h, w), mode="bilinear", align_corners=False)
            out.append(m[:, 0] > threshold)
        return torch.cat(out) if out else torch.zeros((0, h, w), dtype=torch.bool)
    out = torch.zeros(n, h * w, dtype=torch.bool, device=masks.device)
    for k, values, top, left in frame_windows(masks, p, orig_hw, boxes, threshold, chunk):
        _scatter_windows(out, k, values, top, left, (h, w))
    return out.view(n, h, w)


def _frame_spans(
    boxes: torch.Tensor, p: LetterboxParams, orig_hw: tuple[int, int]
) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Per axis (x, then y), the first frame pixel and pixel count ``[N]`` whose bilinear
    taps can reach a non-zero content pixel of each box's input-resolution mask."""
    h, w = orig_hw
    b = boxes.detach().float()
    spans = []
    for lo, hi, size, offset, new, dst in (
        (b[:, 0], b[:, 2], p.out_w, p.left, p.new_w, w),
        (b[:, 1], b[:, 3], p.out_h, p.top, p.new_h, h),
    ):
        # Content pixels [c0, c1) that can be non-zero; frame pixels whose taps reach them,
        # u = (x + 0.5) · new / dst − 0.5 in [c0 − 1, c1), plus one pixel of margin.
        first, count = _pixel_span(lo, hi, size)
        c0 = (first - offset).clamp(0, new).float()
        c1 = (first + count - offset).clamp(0, new).float()
        f0 = (torch.ceil((c0 - 0.5) * (dst / new) - 0.5) - 1).clamp(0, dst)
        f1 = (torch.ceil((c1 + 0.5) * (dst / new) - 0.5) + 1).clamp(0, dst)
        f1 = torch.where(c1 > c0, f1, f0)
        spans.append((f0.long(), (f1 - f0).long()))
    return spans


def window_to_frame(
    values: torch.Tensor,
    top: torch.Tensor,
    left: torch.Tensor,
    p: LetterboxParams,
    orig_hw: tuple[int, int],
    boxes: torch.Tensor,
    threshold: float = 0.5,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`frame_windows` of masks given as input-resolution windows (what
    :func:`mask_windows` yields with ``threshold=None``: ``values float [m, sy, sx]``, 0 outside
    each detection's box, at ``(top, left) [m]`` in input pixels; ``boxes [m, 4]`` xyxy input
    pixels): ``(values bool [m, fy, fx], top [m], left [m])`` in frame pixels, the same pixels
    as the dense path, without ever building an input-size map."""
    local = F.pad(values.float(), (1, 1, 1, 1))  # the zero border _resize_window reads
    (fx, nx), (fy, ny) = _frame_spans(boxes, p, orig_hw)
    origin = (top - p.top, left - p.left)  # window origin in content pixels
    return _resize_window(local, (fx, nx), (fy, ny), orig_hw, threshold, (p.new_h, p.new_w), origin)


def frame_windows(
    masks: torch.Tensor,
    p: LetterboxParams,
    orig_hw: tuple[int, int],
    boxes: torch.Tensor,
    threshold: float = 0.5,
    chunk: int = 32,
) -> Iterator[tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]]:
    """:func:`masks_to_frame` with ``boxes`` and a frame size different from the letterbox
    content, without the full-frame output: per chunk, ``(k [m], values bool [m, sy, sx],
    top [m], left [m])`` as in :func:`mask_windows`, in frame pixels."""
    n = masks.shape[0]
    if boxes.shape != (n, 4):
        raise ValueError(f"expected boxes [{n}, 4], got {tuple(boxes.shape)}")
    if n == 0:
        return
    h, w = orig_hw
    content = masks[:, p.top : p.top + p.new_h, p.left : p.left + p.new_w]
    (fx, nx), (fy, ny) = _frame_spans(boxes, p, orig_hw)
    order = (nx * ny).argsort(descending=True)
    for k in _size_chunks(order, nx, ny, chunk):
        values, top, left = _resize_window(
            content[k].float(), (fx[k], nx[k]), (fy[k], ny[k]), (h, w), threshold
        )
        yield k, values, top, left
