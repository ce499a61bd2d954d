"""Constant-velocity Kalman filter of one object's box in image pixels (ByteTrack's motion
model, docs/tracking.md §3), with the camera's motion applied before each prediction.

State ``x = [cx, cy, w, h, vx, vy, vw, vh]`` (centre, size, their velocities in px/frame);
measurement ``z = [cx, cy, w, h]``. Noise scales with the box height, as in SORT/ByteTrack:
a tall near person moves more pixels per frame than a small far one.
"""

from __future__ import annotations

import numpy as np

from slimseg.dynamic.camera_motion import CameraMotion, local_scale

STD_POSITION = 1.0 / 20  # measurement and process noise of position, × box height
STD_VELOCITY = 1.0 / 160  # process noise of velocity, × box height

_Q_UNIT = np.r_[[STD_POSITION**2] * 4, [STD_VELOCITY**2] * 4]  # process noise / height^2


def xyxy_to_cxcywh(box: np.ndarray) -> np.ndarray:
    """``[4]`` xyxy → ``[4]`` centre x, centre y, width, height."""
    x0, y0, x1, y1 = np.asarray(box, np.float64)
    return np.array([(x0 + x1) / 2, (y0 + y1) / 2, x1 - x0, y1 - y0])


def cxcywh_to_xyxy(c: np.ndarray) -> np.ndarray:
    """``[4]`` centre x, centre y, width, height → ``[4]`` xyxy."""
    cx, cy, w, h = c
    return np.array([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2])


class BoxKalman:
    """One box's filter: :meth:`predict` once per frame (camera motion first), then
    :meth:`update` with the matched detection's box, if any."""

    def __init__(self, box_xyxy: np.ndarray) -> None:
        z = xyxy_to_cxcywh(box_xyxy)
        self.x = np.r_[z, np.zeros(4)]
        h = max(z[3], 1.0)
        std = np.r_[[2 * STD_POSITION * h] * 4, [10 * STD_VELOCITY * h] * 4]
        self.P = np.diag(std**2)

    @property
    def box(self) -> np.ndarray:
        """The current estimate as ``[4]`` xyxy px."""
        return cxcywh_to_xyxy(self.x[:4])

    @property
    def velocity(self) -> np.ndarray:
        """Centre velocity ``[2]`` px/frame (the object's own, after camera compensation)."""
        return self.x[4:6].copy()

    @property
    def centre(self) -> np.ndarray:
        """The box centre ``[2]`` (x, y) px."""
        return self.x[:2].copy()

    def place(self, centre: np.ndarray) -> None:
        """Put the (predicted) box centre at ``centre [2]``: a measured position of the object
        replaces the constant-velocity step (size, velocity and covariance are kept)."""
        self.x[:2] = centre

    def predict(self, motion: CameraMotion, scale: float | None = None) -> None:
        """Move the state through the camera's motion, then one constant-velocity step.
        ``scale``: the motion's local scale when the caller knows it is the same everywhere
        (a similarity), else computed at the box centre."""
        x = self.x
        if motion.ok:
            hm = motion.H
            cx, cy = x[0], x[1]
            w = hm[2, 0] * cx + hm[2, 1] * cy + hm[2, 2]
            s = local_scale(hm, (cx, cy)) if scale is None else scale
            x[0] = (hm[0, 0] * cx + hm[0, 1] * cy + hm[0, 2]) / w
            x[1] = (hm[1, 0] * cx + hm[1, 1] * cy + hm[1, 2]) / w
            x[2:4] *= s
            x[6:8] *= s
        h = max(x[3], 1.0)
        x[:4] += x[4:]  # x <- F x
        p = self.P  # P <- F P F^T + Q, F = [[I, I], [0, I]], in place
        p[:4] += p[4:]
        p[:, :4] += p[:, 4:]
        p.flat[::9] += _Q_UNIT * (h * h)
        x[2:4] = np.maximum(x[2:4], 1.0)

    def update(self, box_xyxy: np.ndarray) -> None:
        """Correct the state with a measured box ``[4]`` xyxy."""
        z = xyxy_to_cxcywh(box_xyxy)
        h = max(self.x[3], 1.0)
        hp = self.P[:4]  # H P: the measurement picks the first four state rows
        s = hp[:, :4] + np.eye(4) * (STD_POSITION * h) ** 2  # H P H^T + R
        k = np.linalg.solve(s, hp).T  # P H^T S^-1 (S symmetric)
        self.x = self.x + k @ (z - self.x[:4])
        self.P = self.P - k @ hp  # (I - K H) P
