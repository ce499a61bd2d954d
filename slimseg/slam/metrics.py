"""Trajectory errors with evo (the field's standard tool; GPL-3.0, optional ``[slam]`` extra).

Conventions (stated in every report):
- association: each estimated pose to the ground-truth pose with the nearest stamp, at most
  ``MAX_DT`` = 0.02 s apart (TUM's ``associate.py`` / ``evaluate_ate.py`` default);
- ATE: evo APE on the translation part after SE(3) Umeyama alignment, no scale (RGB-D has
  metric depth): RMSE and standard deviation in metres;
- RPE: evo RPE on consecutive pose pairs, translation (m) and rotation angle (deg), for a
  delta of 1 frame and of ``round(fps)`` frames (1 s at the sequence's rate: TUM's per-second
  drift), RMSE over pairs, no alignment (relative errors do not need one);
- floor: the ATE of a camera that never moves, after the best rigid alignment — a single point
  aligned to the ground truth lands on its centroid, so it is the RMS distance of the
  ground-truth positions from their centroid (evo's Umeyama is degenerate on it).
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass

import numpy as np

from slimseg.data.bags.poses import degenerate
from slimseg.data.tum import MAX_DT
from slimseg.errors import SlimsegError
from slimseg.slam.engines import EXTRA_HINT


@dataclass(frozen=True)
class TrajectoryScore:
    """Errors of one estimated trajectory: ATE RMSE / std (m); RPE RMSE per frame and per
    second, translation (m) and rotation (deg); ``matched`` estimated poses associated."""

    ate_rmse: float
    ate_std: float
    rpe_trans_frame: float
    rpe_rot_frame: float
    rpe_trans_s: float
    rpe_rot_s: float
    matched: int

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def _evo():
    try:
        from evo.core import metrics, sync, trajectory, units
        from evo.main_ape import ape
        from evo.main_rpe import rpe
    except ImportError:
        raise SlimsegError(
            f"trajectory scoring needs the optional evo package: {EXTRA_HINT} (GPL-3.0)"
        ) from None
    return metrics, sync, trajectory, units, ape, rpe


def to_evo(rows: np.ndarray):
    """TUM rows ``[K, 8]`` (quaternion xyzw) → ``evo.core.trajectory.PoseTrajectory3D``."""
    _, _, trajectory, *_ = _evo()
    rows = np.asarray(rows, np.float64).reshape(-1, 8)
    return trajectory.PoseTrajectory3D(
        positions_xyz=rows[:, 1:4],
        orientations_quat_wxyz=rows[:, [7, 4, 5, 6]],
        timestamps=rows[:, 0],
    )


def score(gt: np.ndarray, est: np.ndarray, fps: float, max_dt: float = MAX_DT) -> TrajectoryScore:
    """Score TUM rows ``est [K, 8]`` against ``gt [G, 8]`` (see the module docstring).
    Raises ``SlimsegError`` when fewer than 3 poses associate (nothing to align)."""
    metrics, sync, _, units, ape, rpe = _evo()
    bad = np.flatnonzero(~np.isfinite(np.asarray(est, np.float64).reshape(-1, 8)).all(1))
    if len(bad):
        raise SlimsegError(f"the estimate's pose {bad[0] + 1} is not finite (nan or inf)")
    ref, cand = sync.associate_trajectories(to_evo(gt), to_evo(est), max_diff=max_dt)
    n = cand.num_poses
    if n < 3:
        raise SlimsegError(f"only {n} estimated poses within {max_dt} s of a ground-truth stamp")
    why = degenerate(np.asarray(cand.positions_xyz))
    if why:  # the engine's estimate: no rigid alignment exists, so no ATE
        raise SlimsegError(f"the estimate {why}: it cannot be aligned to the ground truth")
    a = ape(ref, cand, metrics.PoseRelation.translation_part, align=True, correct_scale=False)
    rel = {}
    for name, delta in (("frame", 1), ("s", max(round(fps), 1))):
        for kind, relation in (
            ("trans", metrics.PoseRelation.translation_part),
            ("rot", metrics.PoseRelation.rotation_angle_deg),
        ):
            if n <= delta:
                rel[f"rpe_{kind}_{name}"] = float("nan")
                continue
            # evo's rpe reduces both trajectories to the pairs' poses in place: fresh copies
            r = rpe(copy.deepcopy(ref), copy.deepcopy(cand), relation, delta=delta,
                    delta_unit=units.Unit.frames, all_pairs=True)  # fmt: skip
            rel[f"rpe_{kind}_{name}"] = float(r.stats["rmse"])
    return TrajectoryScore(float(a.stats["rmse"]), float(a.stats["std"]), matched=n, **rel)


def still_floor(gt: np.ndarray) -> float:
    """ATE RMSE (m) of a camera that never moves, best-aligned: RMS distance of the
    ground-truth positions ``gt[:, 1:4]`` from their centroid."""
    p = np.asarray(gt, np.float64)[:, 1:4]
    return float(np.sqrt(((p - p.mean(0)) ** 2).sum(1).mean()))


def aligned_positions(gt: np.ndarray, est: np.ndarray, max_dt: float = MAX_DT) -> np.ndarray:
    """Positions ``[K, 3]`` (m) of the associated estimated poses after the ATE's SE(3)
    Umeyama alignment to ``gt`` (for plots)."""
    _, sync, *_ = _evo()
    ref, cand = sync.associate_trajectories(to_evo(gt), to_evo(est), max_diff=max_dt)
    cand.align(ref, correct_scale=False)
    return np.asarray(cand.positions_xyz)
