"""TUM trajectory rows (``t tx ty tz qx qy qz qw``: seconds, metres, unit quaternion with the
scalar last; camera-to-world) ↔ 4×4 matrices, and the text file format."""

from __future__ import annotations

import numpy as np


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """``[qx, qy, qz, qw]`` (normalised here) → rotation ``float64 [3, 3]``."""
    x, y, z, w = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Rotation ``[3, 3]`` → ``[qx, qy, qz, qw]`` with ``qw ≥ 0`` (Shepperd's branch choice)."""
    m = np.asarray(r, np.float64)
    tr = np.trace(m)
    if tr > 0:
        s = 2 * np.sqrt(tr + 1)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2 * np.sqrt(1 + m[i, i] - m[j, j] - m[k, k])
        q = [0.0, 0.0, 0.0, (m[k, j] - m[j, k]) / s]
        q[i] = s / 4
        q[j] = (m[j, i] + m[i, j]) / s
        q[k] = (m[k, i] + m[i, k]) / s
    q = np.array(q)
    return q if q[3] >= 0 else -q


def matrix_to_tum(stamp: float, pose: np.ndarray) -> np.ndarray:
    """``float64 [8]`` TUM row of a camera-to-world ``pose [4, 4]`` at ``stamp`` s."""
    return np.concatenate([[stamp], pose[:3, 3], matrix_to_quat(pose[:3, :3])])


def tum_to_matrices(rows: np.ndarray) -> np.ndarray:
    """TUM rows ``[K, 8]`` → poses ``float64 [K, 4, 4]``."""
    out = np.tile(np.eye(4), (len(rows), 1, 1))
    for i, r in enumerate(rows):
        out[i, :3, :3] = quat_to_matrix(r[4:8])
        out[i, :3, 3] = r[1:4]
    return out
