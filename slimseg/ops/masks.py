"""Instance masks from prototype masks and per-detection coefficients, and back to the frame.

The exact rule, which a C++ runtime follows step by step to get the same pixels
(``H × W`` network input, ``Hp × Wp`` prototypes, usually ``H/4 × W/4``):

:func:`assemble_masks` (per detection, boxes xyxy in input pixels):

1. ``prob = sigmoid(coeffs · proto)``: a ``[Hp, Wp]`` map, float32;
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
:class:`~slimseg.data.letterbox.LetterboxParams` ``p``):

1. take rows ``top : top + new_h`` and columns ``left : left + new_w`` (drop the padding);
2. as float32 (``True`` → 1.0), bilinear resize ``new_h × new_w → h × w`` with half-pixel
   centres and no antialiasing (step 3 above; skipped when the sizes are equal);
3. ``mask = value > 0.5``.

This is the exact inverse of the image letterbox (which resizes ``h × w → new_h × new_w``),
so masks land on the frame without the 1–12 px shifts seen in runtimes that round the
padding differently. Resizing probabilities (``assemble_masks(..., threshold=None)``) instead
of binary masks gives smoother edges when the frame is larger than the input.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from slimseg.data.letterbox import LetterboxParams


def _window(boxes: torch.Tensor, h: int, w: int, centre: bool) -> torch.Tensor:
    """``bool [N, h, w]``: pixels inside xyxy ``boxes [N, 4]`` (pixel centre rule if
    ``centre``, else any overlap of the pixel's unit square)."""
    cols = torch.arange(w, device=boxes.device, dtype=boxes.dtype)
    rows = torch.arange(h, device=boxes.device, dtype=boxes.dtype)
    x1, y1, x2, y2 = (boxes[:, k, None] for k in range(4))
    if centre:
        in_x = (cols + 0.5 >= x1) & (cols + 0.5 < x2)
        in_y = (rows + 0.5 >= y1) & (rows + 0.5 < y2)
    else:
        in_x = (cols + 1 > x1) & (cols < x2)
        in_y = (rows + 1 > y1) & (rows < y2)
    return in_y[:, :, None] & in_x[:, None, :]


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
    ``threshold`` is ``None``. Detections are processed ``chunk`` at a time to bound memory
    (``chunk · H · W`` floats). ``proto_crop`` also crops at prototype resolution (off by
    default, see the module docstring for why and for the exact steps).
    """
    if coeffs.ndim != 2 or proto.ndim != 3 or coeffs.shape[1] != proto.shape[0]:
        raise ValueError(
            f"expected coeffs [N, nm] and proto [nm, Hp, Wp], got {tuple(coeffs.shape)} and "
            f"{tuple(proto.shape)}"
        )
    if boxes.shape != (coeffs.shape[0], 4):
        raise ValueError(f"expected boxes [{coeffs.shape[0]}, 4], got {tuple(boxes.shape)}")
    h, w = input_hw
    nm, hp, wp = proto.shape
    flat = proto.reshape(nm, hp * wp).float()
    to_proto = torch.tensor([wp / w, hp / h, wp / w, hp / h], device=boxes.device)
    out = []
    for s in range(0, coeffs.shape[0], chunk):
        c, b = coeffs[s : s + chunk].float(), boxes[s : s + chunk].float()
        prob = (c @ flat).sigmoid().view(-1, hp, wp)
        if proto_crop:
            prob = prob * _window(b * to_proto, hp, wp, centre=False)
        prob = F.interpolate(prob[:, None], size=(h, w), mode="bilinear", align_corners=False)
        prob = prob[:, 0] * _window(b, h, w, centre=True)
        out.append(prob if threshold is None else prob > threshold)
    if not out:
        dtype = torch.float32 if threshold is None else torch.bool
        return torch.zeros((0, h, w), dtype=dtype, device=coeffs.device)
    return torch.cat(out)


def masks_to_frame(
    masks: torch.Tensor,
    p: LetterboxParams,
    orig_hw: tuple[int, int],
    threshold: float = 0.5,
    chunk: int = 32,
) -> torch.Tensor:
    """``[N, H, W]`` masks (bool) or probabilities (float) at network-input resolution →
    ``bool [N, h, w]`` on the source frame ``orig_hw = (h, w)``.

    Removes the letterbox padding, resizes bilinearly to the frame and thresholds
    (``value > threshold``); see the module docstring for the exact steps.
    """
    if masks.ndim != 3 or tuple(masks.shape[1:]) != (p.out_h, p.out_w):
        raise ValueError(
            f"expected masks [N, {p.out_h}, {p.out_w}] (the letterbox output size), got "
            f"{tuple(masks.shape)}"
        )
    h, w = orig_hw
    content = masks[:, p.top : p.top + p.new_h, p.left : p.left + p.new_w]
    out = []
    for s in range(0, content.shape[0], chunk):
        m = content[s : s + chunk].float()
        if (p.new_h, p.new_w) != (h, w):
            m = F.interpolate(m[:, None], size=(h, w), mode="bilinear", align_corners=False)
            m = m[:, 0]
        out.append(m > threshold)
    if not out:
        return torch.zeros((0, h, w), dtype=torch.bool, device=masks.device)
    return torch.cat(out)
