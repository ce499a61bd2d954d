"""The frames each evaluated condition hands to a SLAM engine.

Kinds of condition:
- ``raw``: the sequence's frames;
- ``masked``: a dynamic mask per frame (``<rgb timestamp>.png``, nonzero = dynamic, as
  ``slimseg dynamic`` writes them, or the ground-truth ``dynamic/``). ORB-SLAM3 has no mask
  input, so the region is removed from what it sees
  (:func:`slimseg.dynamic.remove_region.remove_dynamic`: Telea inpainting, depth zeroed).
  The dense engine also
  gets the complement as its valid-pixel mask. The mask is first dilated by the condition's
  ``dilation_px``: the masking settings' dilation for ground-truth masks, 0 for masks that
  already carry it (made by a mode, or by ``slimseg dynamic`` and read with ``--masks``);
  A masked condition may ``combine`` its masks with the ground-truth ``dynamic/`` ones
  (:mod:`slimseg.slam.diagnostic`), to say where a mask's ATE gap comes from: ``within``
  keeps only the mask pixels near a dynamic pixel (the masks at perfect precision, their
  recall unchanged); ``plus`` adds the ground truth (the masks at perfect recall, their false
  positives kept). On held-out walking_xyz s131, a model's masks at 8x the ground-truth
  masks' ATE came to 1.02x within the truth and 6.4x plus it: their gap was precision
  (docs/slam_eval.md);
- ``replaced``: whole replacement frames, e.g. ``restored/rgb/<ts>.png`` +
  ``restored/depth/<ts>.png`` from ``slimseg dynamic --restore``, or a synthetic sequence's
  true static ``background/`` (the oracle).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from slimseg.data.frame_source import FrameSource
from slimseg.data.images import decode_file
from slimseg.data.tum import depth_metres, mask_name
from slimseg.dynamic.remove_region import remove_dynamic
from slimseg.dynamic.seg_box import dilate
from slimseg.errors import SlimsegError
from slimseg.slam.diagnostic import NEAR_TRUTH_PX
from slimseg.slam.engines import EngineFrame

PathsFor = Callable[[int], tuple[Path, Path]]


@dataclass(frozen=True)
class Condition:
    """One row of the results table. ``kind``: raw | masked | replaced; ``masks``: folder of
    ``<rgb ts>.png`` masks (masked); ``frames``: ``i → (rgb path, depth path)`` of the
    replacement frames (replaced); ``masking_ms``: time per frame to make the masks or frames
    (None: given, e.g. ground truth); ``note``: how they were made; ``dilation_px``: pixels
    added around the masks before the region is removed (masked); ``truth``: the
    ground-truth ``dynamic/`` folder the masks are combined with, and ``combine``: how
    (``within`` or ``plus``, :mod:`slimseg.slam.diagnostic`; empty: not)."""

    name: str
    kind: str
    masks: Path | None = None
    frames: PathsFor | None = None
    masking_ms: float | None = None
    note: str = ""
    dilation_px: int = 0
    truth: Path | None = None
    combine: str = ""


def check_masks(seq: FrameSource, folder: Path) -> None:
    """Raise ``SlimsegError`` unless ``folder`` holds a mask for every associated frame."""
    if not folder.is_dir():
        raise SlimsegError(f"masks folder {folder} does not exist")
    missing = [mask_name(t) for (t, _), _ in seq.frames if not (folder / mask_name(t)).is_file()]
    if missing:
        raise SlimsegError(
            f"masks folder {folder} lacks {len(missing)} of {len(seq)} frames (e.g. "
            f"{missing[0]}); make it with slimseg dynamic --sequence {seq.root} --out DIR"
        )


def oracle_paths(seq: FrameSource) -> PathsFor:
    """A synthetic sequence's true static background: ``background/<rgb path>`` and
    ``background/<depth path>`` of each frame."""
    return lambda i: (
        seq.root / "background" / seq.frames[i][0][1],
        seq.root / "background" / seq.frames[i][1][1],
    )


def restored_paths(seq: FrameSource, folder: Path) -> PathsFor:
    """``slimseg dynamic --restore`` output under ``folder``: ``restored/{rgb,depth}/<ts>.png``."""
    return lambda i: (
        folder / "rgb" / mask_name(seq.frames[i][0][0]),
        folder / "depth" / mask_name(seq.frames[i][0][0]),
    )


def condition_frames(
    seq: FrameSource,
    cond: Condition,
    limit: int | None = None,
    progress: bool = False,
) -> list[EngineFrame]:
    """Every associated frame of ``seq`` (the first ``limit``) as ``cond`` presents it to an
    engine (see the module docstring). Missing files raise ``SlimsegError`` naming them."""
    n = len(seq) if limit is None else min(limit, len(seq))
    out = []
    for i in tqdm(range(n), desc=cond.name, unit="frame", disable=not progress):
        rgb, depth, stamp = seq.load(i)
        static = None
        if cond.kind == "masked":
            path = cond.masks / mask_name(stamp)
            m = decode_file(path, cv2.IMREAD_GRAYSCALE)
            if m is None:
                raise SlimsegError(f"missing or unreadable dynamic mask {path}")
            if m.shape != rgb.shape[:2]:
                raise SlimsegError(f"mask {path} is {m.shape[::-1]}, frames are {rgb.shape[1::-1]}")
            region = dilate(m > 0, cond.dilation_px).astype(bool)
            if cond.combine:
                region = _combined(region, cond, stamp)
            rgb, depth = remove_dynamic(rgb, depth, region)
            static = np.where(region, 0, 255).astype(np.uint8)
        elif cond.kind == "replaced":
            rgb, depth = _replacement(seq, cond.frames(i), rgb.shape[:2])
        out.append(EngineFrame(rgb, depth.astype(np.float32), stamp, static))
    return out


def _combined(region: np.ndarray, cond: Condition, stamp: float) -> np.ndarray:
    """``region bool [H, W]`` combined with the frame's ground-truth mask as ``cond.combine``
    says (module docstring)."""
    path = cond.truth / mask_name(stamp)
    t = decode_file(path, cv2.IMREAD_GRAYSCALE)
    if t is None:
        raise SlimsegError(f"missing or unreadable ground-truth mask {path}")
    if t.shape != region.shape:
        raise SlimsegError(f"ground-truth mask {path} is {t.shape[::-1]}, frames are "
                           f"{region.shape[::-1]}")  # fmt: skip
    if cond.combine == "within":
        return region & dilate(t > 0, NEAR_TRUTH_PX).astype(bool)
    return region | (t > 0)


def _replacement(seq: FrameSource, paths: tuple[Path, Path], hw: tuple[int, int]):
    rgb_path, depth_path = paths
    bgr = decode_file(rgb_path, cv2.IMREAD_COLOR)  # the shared decoder (slimseg.data.images)
    raw = decode_file(depth_path, cv2.IMREAD_UNCHANGED)
    for img, p in ((bgr, rgb_path), (raw, depth_path)):
        if img is None:
            raise SlimsegError(f"missing or unreadable replacement frame {p}")
        if img.shape[:2] != hw:
            raise SlimsegError(f"replacement frame {p} is not {hw[1]}x{hw[0]}")
    depth = depth_metres(raw, seq.camera.depth_scale)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), depth
