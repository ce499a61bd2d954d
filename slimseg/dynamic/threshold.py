"""Mobility priors → dynamic keypoints: the substation paper's Eq. 1 and 3 (docs/papers.md §2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slimseg.dynamic.knobs import papers

M_TH_START = papers("m_th_start")
M_TH_STEP = papers("m_th_step")
DYNAMIC_FRAME_M_TH = 0.5
# Eq. 3 is printed garbled in the paper ("m_cd <= 1/N"); we test the ratio m_cd / N against
# this fraction: a frame is a dynamic keyframe when more than 5 % of its points sit on objects
# with mobility > 0.5.
DYNAMIC_FRAME_RATIO = papers("frame_ratio")


def inside(points: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """``bool [K, N]``: which of ``masks bool [K, H, W]`` hold each of ``points [N, 2]`` (x, y)
    px, each point's pixel rounded (half to even) and clipped to the frame."""
    if len(masks) == 0 or len(points) == 0:
        return np.zeros((len(masks), len(points)), bool)
    h, w = masks.shape[1:]
    x = np.clip(np.round(points[:, 0]).astype(int), 0, w - 1)
    y = np.clip(np.round(points[:, 1]).astype(int), 0, h - 1)
    return masks[:, y, x]


def keypoint_mobility(keypoints: np.ndarray, masks: np.ndarray, mobility: np.ndarray) -> np.ndarray:
    """Mobility under each keypoint: the highest prior of the masks containing it, else 0.

    ``keypoints [N, 2]`` (x, y) px, ``masks bool [K, H, W]``, ``mobility [K]`` → ``[N]``.
    """
    n = len(keypoints)
    if n == 0 or len(masks) == 0:
        return np.zeros(n, np.float32)
    hits = inside(keypoints, masks)  # [K, N]
    return np.where(hits, np.asarray(mobility, np.float32)[:, None], 0.0).max(0)


@dataclass(frozen=True)
class ThresholdResult:
    """Eq. 1 outcome: ``dynamic [N]`` bool; ``m_th`` used (None: gave up, nothing masked)."""

    dynamic: np.ndarray
    m_th: float | None

    @property
    def static_count(self) -> int:
        return int((~self.dynamic).sum())


def adaptive_threshold(
    point_mobility: np.ndarray, min_static: int, start: float = M_TH_START, step: float = M_TH_STEP
) -> ThresholdResult:
    """Eq. 1: a point is dynamic iff its mobility m > m_th. Start at ``start``; while fewer
    than ``min_static`` points stay static, raise m_th by ``step``; once m_th exceeds 1.0
    (nothing can be dynamic) and still too few points remain, give up masking the frame."""
    m = np.asarray(point_mobility, np.float32)
    m_th = start
    while m_th <= 1.0 + 1e-9:
        dynamic = m > m_th + 1e-9
        if int((~dynamic).sum()) >= min_static:
            return ThresholdResult(dynamic, round(m_th, 4))
        m_th += step
    return ThresholdResult(np.zeros(len(m), bool), None)


def is_dynamic_frame(point_mobility: np.ndarray, ratio: float = DYNAMIC_FRAME_RATIO) -> bool:
    """Eq. 3 (our reading): m_cd = points with mobility > 0.5; dynamic iff m_cd / N > ratio."""
    m = np.asarray(point_mobility)
    if len(m) == 0:
        return False
    return float((m > DYNAMIC_FRAME_M_TH).mean()) > ratio
