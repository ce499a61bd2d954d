"""Background restoration of removed (dynamic) regions from neighbouring frames (VTD-SLAM).

For frame ``i`` with removed region ``M_i`` (the dynamic mask, slightly dilated):

1. **Reference frames** (VTD-SLAM's Eq. 10-12 are not in our notes; this is our rule). The
   candidates are frames ``i ± stride·k`` within ``±window`` frames. Each candidate's ORB
   features outside its own removed region are matched with frame ``i``'s (ratio test), and a
   homography ``H`` (candidate → ``i``, RANSAC 1.5 px) is fitted. A candidate is *eligible* with at
   least ``min_matches`` homography inliers; it is *preferred* when, in addition, the median
   displacement of those inliers (the parallax, px) is at least ``min_parallax``, i.e. it sees
   the scene from a different viewpoint. References are then picked greedily: each time the
   candidate whose warped usable pixels (inside its frame, outside its own removed region)
   cover the most still-uncovered pixels of ``M_i``; preferred candidates first, eligible ones
   only when fewer than ``min_refs`` preferred ones add coverage. Picking stops at ``max_refs``
   or when no candidate adds coverage. So frames whose removed region overlaps ``M_i`` the
   least, i.e. where the mover has walked away, win. If fewer than ``min_refs`` were picked
   (one frame already covers everything), the preferred candidates with the most inliers
   are added up to ``min_refs``: alternatives for PatchMatch at no extra coverage.
2. **Warp** every reference to frame ``i`` with its homography (RGB bilinear, depth nearest,
   usable mask nearest and eroded by 1 px so that no interpolated mover colour is usable).
3. **Fill** ``M_i`` with :func:`slimseg.dynamic.patchmatch.patchmatch` over the warped
   references plus frame ``i``'s own known pixels (a last resort where no reference sees the
   background). Depth is copied from the same source pixels (0 = invalid stays allowed), so
   colour and depth stay consistent. Depth values are copied, not re-projected: the camera
   moves a few centimetres within the window, far less than the depth noise of a TUM sensor.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from slimseg.dynamic.epipolar import OrbFeatures, match_features, orb_features
from slimseg.dynamic.modes import KEYPOINTS
from slimseg.dynamic.patchmatch import NNField, patchmatch
from slimseg.dynamic.seg_box import dilate

WINDOW = 15
STRIDE = 3
MIN_MATCHES = 30
MIN_PARALLAX_PX = 1.0
MIN_REFS, MAX_REFS = 2, 4
H_RANSAC_PX = 1.5  # a looser threshold lets skewed homographies win on blocky texture


@dataclass
class FrameData:
    """One frame for restoration: ``rgb uint8 [H, W, 3]``, ``depth float32 [H, W]`` metres,
    ``removed bool [H, W]`` (the region to fill, already dilated) and ``features``: ORB
    features detected outside ``removed``."""

    rgb: np.ndarray
    depth: np.ndarray
    removed: np.ndarray
    features: OrbFeatures

    @classmethod
    def build(
        cls, rgb: np.ndarray, depth: np.ndarray, removed: np.ndarray, count: int = KEYPOINTS
    ) -> FrameData:
        """Validate shapes and detect the static ORB features."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"rgb must be uint8 [H, W, 3], got {rgb.dtype} {rgb.shape}")
        removed = np.asarray(removed, bool)
        depth = np.asarray(depth, np.float32)
        if removed.shape != rgb.shape[:2] or depth.shape != rgb.shape[:2]:
            raise ValueError(
                f"rgb {rgb.shape[:2]}, depth {depth.shape} and removed mask {removed.shape} "
                "must have the same height and width"
            )
        feats = orb_features(rgb, count, mask=~removed)
        return cls(rgb, depth, removed, feats)


@dataclass
class Reference:
    """A chosen reference frame: its ``index``, homography ``inliers``, ``parallax_px``
    (median displacement of the inliers), ``gain`` (fraction of the removed region it covered
    first) and ``homography [3, 3]`` reference → target."""

    index: int
    inliers: int
    parallax_px: float
    gain: float
    homography: np.ndarray


def removed_region(mask: np.ndarray, dilation_px: int = 2) -> np.ndarray:
    """``bool [H, W]`` region to fill from a dynamic mask (nonzero = dynamic), dilated a little
    so that mover edges (anti-aliasing, mask errors) are replaced too."""
    return dilate(np.asarray(mask) > 0, dilation_px).astype(bool)


def _usable_warp(ref: FrameData, hom: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    h, w = hw
    usable = (~ref.removed).astype(np.uint8)
    warped = cv2.warpPerspective(usable, hom, (w, h), flags=cv2.INTER_NEAREST, borderValue=0)
    return cv2.erode(warped, np.ones((3, 3), np.uint8)).astype(bool)


def select_references(
    target: FrameData,
    candidates: dict[int, FrameData],
    min_matches: int = MIN_MATCHES,
    min_parallax: float = MIN_PARALLAX_PX,
    min_refs: int = MIN_REFS,
    max_refs: int = MAX_REFS,
) -> list[Reference]:
    """Choose up to ``max_refs`` of ``candidates`` (frame index → data) for ``target`` by the
    rule of the module docstring; ordered by choice (best first)."""
    hw = target.rgb.shape[:2]
    need = target.removed
    n_need = max(int(need.sum()), 1)
    scored = []
    for j, cand in candidates.items():
        pairs = match_features(cand.features, target.features)
        if len(pairs) < max(min_matches, 4):
            continue
        p_ref = cand.features.keypoints[pairs[:, 0]].astype(np.float64)
        p_tgt = target.features.keypoints[pairs[:, 1]].astype(np.float64)
        hom, inl = cv2.findHomography(p_ref, p_tgt, cv2.RANSAC, H_RANSAC_PX)
        if hom is None:
            continue
        inl = inl.ravel().astype(bool)
        if inl.sum() < min_matches:
            continue
        parallax = float(np.median(np.linalg.norm(p_tgt[inl] - p_ref[inl], axis=1)))
        usable = _usable_warp(cand, hom, hw) & need
        scored.append((j, int(inl.sum()), parallax, hom, usable))
    chosen: list[Reference] = []
    covered = np.zeros(hw, bool)
    pool = sorted(scored, key=lambda s: -s[1])  # ties: more inliers first
    while len(chosen) < max_refs:
        gains = [int((s[4] & ~covered).sum()) for s in pool]
        preferred = [k for k, s in enumerate(pool) if gains[k] > 0 and s[2] >= min_parallax]
        eligible = [k for k, s in enumerate(pool) if gains[k] > 0]
        group = preferred or (eligible if len(chosen) < min_refs else [])
        if not group:
            break
        k = max(group, key=lambda k: gains[k])
        j, inliers, parallax, hom, usable = pool.pop(k)
        chosen.append(Reference(j, inliers, parallax, gains[k] / n_need, hom))
        covered |= usable
    extra = [s for s in pool if s[2] >= min_parallax][
        : max(0, min(min_refs, max_refs) - len(chosen))
    ]
    chosen += [Reference(j, inl, par, 0.0, hom) for j, inl, par, hom, _ in extra]
    return chosen


@dataclass
class Restored:
    """Restoration of one frame: ``rgb uint8 [H, W, 3]``, ``depth float32 [H, W]`` metres,
    the ``references`` used, the PatchMatch ``field`` (source index ``len(references)`` = the
    frame itself) and ``coverage``: fraction of the removed region some reference sees."""

    rgb: np.ndarray
    depth: np.ndarray
    references: list[Reference]
    field: NNField | None
    coverage: float


def restore_frame(
    target: FrameData,
    references: list[tuple[FrameData, Reference]],
    patch: int = 7,
    seed: int = 0,
) -> Restored:
    """Fill ``target.removed`` in RGB and depth from the warped ``references`` (see module
    docstring). Without a removed pixel, or without any usable source pixel (the whole frame
    removed and no reference), the frame comes back unchanged."""
    hole = target.removed
    refs = [r for _, r in references]
    if not hole.any():
        return Restored(target.rgb.copy(), target.depth.copy(), refs, None, 1.0)
    h, w = hole.shape
    srcs, deps, valid = [], [], []
    for frame, ref in references:
        if frame.rgb.shape != target.rgb.shape:
            raise ValueError(
                f"reference frame {ref.index} is {frame.rgb.shape}, target {target.rgb.shape}"
            )
        srcs.append(cv2.warpPerspective(frame.rgb, ref.homography, (w, h), flags=cv2.INTER_LINEAR))
        deps.append(
            cv2.warpPerspective(frame.depth, ref.homography, (w, h), flags=cv2.INTER_NEAREST)
        )
        valid.append(_usable_warp(frame, ref.homography, (h, w)))
    coverage = float((np.any(valid, 0) & hole).sum() / hole.sum()) if valid else 0.0
    if hole.all() and coverage == 0.0:  # nothing anywhere to copy from
        return Restored(target.rgb.copy(), target.depth.copy(), refs, None, 0.0)
    srcs.append(target.rgb)
    deps.append(target.depth)
    valid.append(~hole)
    sources = np.stack(srcs).astype(np.float32) / 255.0
    field = patchmatch(
        target.rgb.astype(np.float32) / 255.0,
        hole,
        sources,
        np.stack(valid),
        patch=patch,
        seed=seed,
    )
    rgb = np.clip(np.round(field.image * 255.0), 0, 255).astype(np.uint8)
    depth = field.gather(np.stack(deps), target.depth)
    return Restored(rgb, depth.astype(np.float32), refs, field, coverage)
