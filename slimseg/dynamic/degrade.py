"""The degrading masking rule of the ``slimseg`` preset: where static support runs short, the
least certain masks are given up first, one at a time; a confident mover never is.

Eq. 1 (:mod:`slimseg.dynamic.threshold`, the ``papers`` preset) raises one mobility threshold
over all objects: when a few low-score detections paint large regions of wall, the threshold
climbs past the person's prior and every mask goes at once, the walkers' with them. This rule
keeps Eq. 1's starting threshold (objects with mobility above ``m_th_start`` are the
candidates) and, while the static support is under ``min_static``, drops the candidate with
the lowest certainty (detection score × mobility) and counts again. Candidates scoring at
least ``keep_score`` are never dropped: a frame may end short of support, but never with a
confident walker handed to SLAM.

Static support is what the SLAM engine can still find outside the mask. ORB-SLAM3 extracts
its features after masking, so it is not the share of keypoints extracted on the whole frame
before it (a mask over half the corners of a textured frame still leaves ORB-SLAM3 its 1000
features elsewhere) but the corners left outside the mask: the caller's ``support`` points,
the FAST corners of ORB-SLAM3's image pyramid at its threshold (:func:`support_points`), or,
where none are given, the keypoints themselves.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from slimseg.dynamic.knobs import papers
from slimseg.dynamic.threshold import inside

# ORB-SLAM3's extractor (its example settings' ORBextractor.iniThFAST, nLevels, scaleFactor):
# the FAST corners it starts from, on every level of its image pyramid. One home:
# slimseg.slam.orbslam3_config writes these into the settings it generates.
FAST_THRESHOLD = 20
PYRAMID_LEVELS = 8
PYRAMID_SCALE = 1.2
# A candidate scoring at least this is never given up by the degrading rule (the ``keep_score``
# masking setting's default).
KEEP_SCORE = papers("keep_score")


def support_points(image: np.ndarray) -> np.ndarray:
    """The corners ORB-SLAM3's extractor starts from: FAST corners (non-maximum suppressed,
    threshold :data:`FAST_THRESHOLD`) on each of :data:`PYRAMID_LEVELS` levels, each
    :data:`PYRAMID_SCALE` times smaller, in level-0 pixels. RGB ``uint8 [H, W, 3]`` or gray
    ``[H, W]`` → ``float32 [P, 2]`` (x, y) px (about 2 ms at 640×480)."""
    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    fast = cv2.FastFeatureDetector_create(threshold=FAST_THRESHOLD, nonmaxSuppression=True)
    h, w = gray.shape
    out = []
    for level in range(PYRAMID_LEVELS):
        scale = PYRAMID_SCALE**level
        size = (round(w / scale), round(h / scale))
        if min(size) < 8:
            break
        img = gray if level == 0 else cv2.resize(gray, size, interpolation=cv2.INTER_LINEAR)
        pts = cv2.KeyPoint_convert(fast.detect(img, None))  # float32 [n, 2], or empty
        out.append(np.asarray(pts, np.float32).reshape(-1, 2) * np.float32(scale))
    return np.concatenate(out) if out else np.zeros((0, 2), np.float32)


@dataclass(frozen=True)
class Degraded:
    """The rule's outcome: ``masked bool [M]`` objects in the dynamic mask, ``dynamic bool [N]``
    per keypoint, ``support`` points left outside the mask, ``dropped``: the candidates given
    up, in the order they went (least certain first)."""

    masked: np.ndarray
    dynamic: np.ndarray
    support: int
    dropped: list[int]


def degrade(
    *,
    regions: np.ndarray,
    mobility: np.ndarray,
    scores: np.ndarray,
    keypoints: np.ndarray,
    support: np.ndarray,
    min_static: int,
    m_th_start: float,
    keep_score: float = KEEP_SCORE,
) -> Degraded:
    """Apply the rule to one frame's objects.

    ``regions bool [M, H, W]`` (dilated, after Eq. 4), ``mobility [M]``, ``scores [M]``,
    ``keypoints [N, 2]`` and ``support [P, 2]`` (x, y) px. An object is a candidate when its
    mobility exceeds ``m_th_start`` (Eq. 1's first step); candidates are dropped in increasing
    score × mobility while fewer than ``min_static`` support
    points lie outside the masked candidates; those scoring ``>= keep_score`` stay. Equal
    certainties: the larger region goes first (then the later object).
    """
    mob = np.asarray(mobility, np.float32).reshape(-1)
    score = np.asarray(scores, np.float32).reshape(-1)
    masked = mob > m_th_start + 1e-9  # Eq. 1's comparison (in float32) at its first threshold
    covers = inside(np.asarray(support, np.float32).reshape(-1, 2), regions)  # [M, P]
    total = covers.shape[1]

    def left() -> int:
        return total - int(covers[masked].any(0).sum()) if masked.any() else total

    have = left()
    dropped: list[int] = []
    certainty = score * mob
    droppable = np.flatnonzero(masked & (score < keep_score)) if have < min_static else []
    # ties (equal scores are common in FP16): the larger region first, then the later object
    area = {int(k): int(regions[k].sum()) for k in droppable}
    order = sorted(droppable, key=lambda k: (certainty[k], -area[int(k)], -k))
    for k in order:
        if have >= min_static:
            break
        masked[k] = False
        dropped.append(int(k))
        have = left()
    hits = inside(np.asarray(keypoints, np.float32).reshape(-1, 2), regions)  # [M, N]
    dynamic = hits[masked].any(0) if masked.any() else np.zeros(hits.shape[1], bool)
    return Degraded(masked, dynamic, have, dropped)
