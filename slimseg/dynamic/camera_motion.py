"""Image motion of the static background between two frames: the track stage's camera-motion
compensation (BoT-SORT's CMC, docs/tracking.md §2).

A 4-degree-of-freedom similarity (rotation, uniform scale, translation; OpenCV's
``estimateAffinePartial2D`` with RANSAC) maps previous to current frame pixels, fitted to the
ORB matches that lie outside every object region (the same ratio-test matches the epipolar
check uses). A full homography fits a rotating camera exactly, but on the few dozen background
matches of a frame full of walkers, and with the parallax of a translating camera, its
perspective terms came out wrong often enough to halve the overlap of a warped person mask
with the next frame's (0.75 → 0.25 mask IoU on a 320×240 walking_xyz sequence); the
similarity cannot bend a mask and kept it (BoT-SORT also uses an affine model). It is stored
as a 3×3 matrix ``H`` all the same. With fewer than :data:`MIN_MATCHES` background matches,
or a fit that RANSAC cannot support, the identity is returned and flagged.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from slimseg.dynamic.epipolar import OrbFeatures, match_features

MIN_MATCHES = 20  # background matches wanted for a fit
RANSAC_PX = 3.0  # reprojection threshold of the similarity fit (px)
MIN_INLIER_SHARE = 0.3  # below this share of inliers the fit is not trusted


@dataclass(frozen=True)
class CameraMotion:
    """``H float64 [3, 3]`` previous → current pixels (a similarity); ``ok``: fitted (False:
    identity, too few background matches); ``matches`` used for the fit and their ``inliers``."""

    H: np.ndarray
    ok: bool
    matches: int = 0
    inliers: int = 0

    @classmethod
    def identity(cls, matches: int = 0) -> CameraMotion:
        return cls(np.eye(3), False, matches, 0)

    def points(self, xy: np.ndarray) -> np.ndarray:
        """Map ``xy float [N, 2]`` previous-frame pixels to the current frame → ``[N, 2]``."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        if len(xy) == 0:
            return xy
        return cv2.perspectiveTransform(xy.reshape(-1, 1, 2), self.H)[:, 0]


def estimate_motion(
    previous: OrbFeatures,
    current: OrbFeatures,
    objects: np.ndarray | None = None,
    pairs: np.ndarray | None = None,
) -> CameraMotion:
    """Background motion (a similarity) from ``previous`` to ``current`` features; matches
    whose current point lies inside any of the ``objects float [K, 4]`` xyxy boxes
    (detections, predicted tracks) are left out. ``pairs``: precomputed
    :func:`~slimseg.dynamic.epipolar.match_features` rows, else matched here, on all the
    features: every fourth of each frame, drawn independently, kept a sixteenth of the true
    pairs, and on walking_rpy 404 fewer than :data:`MIN_MATCHES` were left outside the
    objects in most frames, so the motion fell back to the identity (static pixels' median
    endpoint error 10.5 px per frame against 1.0 px with all; docs/tracking.md §2)."""
    if pairs is None:
        pairs = match_features(previous, current)
    if len(pairs) < MIN_MATCHES:
        return CameraMotion.identity(len(pairs))
    p0 = previous.keypoints[pairs[:, 0]].astype(np.float64)
    p1 = current.keypoints[pairs[:, 1]].astype(np.float64)
    if objects is not None and len(objects):
        b = np.asarray(objects, np.float64).reshape(-1, 4)
        x, y = p1[:, :1], p1[:, 1:]
        inside = (x >= b[:, 0]) & (x < b[:, 2]) & (y >= b[:, 1]) & (y < b[:, 3])  # [M, K]
        keep = ~inside.any(1)
        p0, p1 = p0[keep], p1[keep]
    if len(p0) < MIN_MATCHES:
        return CameraMotion.identity(len(p0))
    aff, inl = cv2.estimateAffinePartial2D(p0, p1, method=cv2.RANSAC,
                                           ransacReprojThreshold=RANSAC_PX)  # fmt: skip
    if aff is None or inl is None or inl.sum() < max(MIN_MATCHES, MIN_INLIER_SHARE * len(p0)):
        return CameraMotion.identity(len(p0))
    return CameraMotion(np.vstack([aff, [0.0, 0.0, 1.0]]), True, len(p0), int(inl.sum()))


def local_scale(h: np.ndarray, xy: tuple[float, float]) -> float:
    """Isotropic scale of the 3×3 transform ``h`` near point ``xy`` (sqrt of the Jacobian's
    determinant): how a small object's size changes under the camera motion."""
    x, y = xy
    p = h @ np.array([x, y, 1.0])
    w = p[2] if abs(p[2]) > 1e-12 else 1e-12
    jac = (h[:2, :2] * w - np.outer(p[:2], h[2, :2])) / (w * w)
    return float(np.sqrt(abs(np.linalg.det(jac))))
