"""Trajectory engines run on prepared frames: ORB-SLAM3 RGB-D (``pyorbslam3``) and a dense
RGB odometry (OpenCV 5 ``cv2.Odometry``, no vocabulary, deterministic).

Both take the frames of one condition as :class:`EngineFrame` (RGB uint8, depth metres,
optional static-pixel mask, timestamp) and return an :class:`EngineRun`: a TUM trajectory
``float64 [K, 8]`` (``t tx ty tz qx qy qz qw``, camera-to-world) and per-frame tracking states.

ORB-SLAM3 has no keypoint-mask input: a masked condition reaches it as an image whose dynamic
region was removed beforehand (see :mod:`slimseg.slam.conditions`); the dense engine also gets
the mask itself (OpenCV's odometry ignores pixels outside it). ``pyorbslam3`` is GPL-3.0 and
optional (``pip install slimseg[slam]``): it is imported only inside :func:`run_orbslam3`.
"""

from __future__ import annotations

import itertools
import logging
import os
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from slimseg.data.frame_source import Camera
from slimseg.data.tum import read_trajectory
from slimseg.errors import SlimsegError
from slimseg.slam.trajectory import matrix_to_tum
from slimseg.utils.extras import install_command

log = logging.getLogger(__name__)

ENGINES = ("orbslam3", "dense")
EXTRA_HINT = install_command("slam")
DENSE_MAX_DEPTH_M = 10.0  # OpenCV's default 4 m drops far walls silently
OK_STATES = ("OK", "OK_KLT")


@dataclass(frozen=True)
class EngineFrame:
    """One frame as the engine sees it: ``rgb uint8 [H, W, 3]``, ``depth_m float32 [H, W]``
    (0 = no depth), ``static uint8 [H, W]`` (255 = usable pixel; None = all), ``stamp`` s."""

    rgb: np.ndarray
    depth_m: np.ndarray
    stamp: float
    static: np.ndarray | None = None


@dataclass
class EngineRun:
    """One run: ``trajectory float64 [K, 8]`` TUM rows, ``states`` per input frame (``OK``,
    ``LOST``, ``RECENTLY_LOST``, ``NOT_INITIALIZED``, …) and the mean tracking time (ms)."""

    trajectory: np.ndarray
    states: list[str] = field(default_factory=list)
    ms_per_frame: float = float("nan")
    late: int = 0
    """realtime feeding: frames fed more than one frame interval after their timestamp (the
    machine could not keep the sequence's rate; the mapping threads got less time than live)"""

    @property
    def lost(self) -> int:
        """Frames without a tracked pose (not initialised yet, lost, or recently lost)."""
        return sum(s not in OK_STATES for s in self.states)

    @property
    def reinitialised(self) -> int:
        """Times tracking came back to OK after a loss (ORB-SLAM3 relocalised in its map or,
        after LOST, started a new one)."""
        ok = [s in OK_STATES for s in self.states]
        seen, count = False, 0
        for prev, cur in itertools.pairwise(ok):
            seen = seen or prev
            count += seen and not prev and cur
        return count


def run_orbslam3(
    frames: Sequence[EngineFrame],
    vocab: Path,
    settings: Path,
    realtime: bool = True,
    log_path: Path | None = None,
    work: Path | None = None,
    speed: float = 1.0,
) -> EngineRun:
    """Track ``frames`` with a fresh ORB-SLAM3 RGB-D system; returns its saved camera
    trajectory (``SaveTrajectoryTUM``: every tracked frame relative to its reference keyframe).

    ``realtime``: feed a frame no earlier than its timestamp after the first (replay at the
    sequence's frame rate, times ``speed``: 0.5 replays at half the rate, which gives the
    mapping threads twice the live time and keeps the schedule on a loaded machine; ``late``
    counts the frames fed behind it). ORB-SLAM3's console
    output goes to ``log_path`` (appended) instead of this process's stdout."""
    slam_mod = import_pyorbslam3()
    work = Path(work or (log_path.parent if log_path else "."))
    states: list[str] = []
    traj_path = work / f".traj.{os.getpid()}.txt"
    with _stdout_to(log_path):
        slam = slam_mod.Slam(
            vocab_file=str(vocab), settings_file=str(settings), sensor=slam_mod.Sensor.RGBD
        )
        try:
            t_track, start, late = 0.0, time.perf_counter(), 0
            interval = _interval(frames)
            for f in frames:
                if realtime:
                    wait = (f.stamp - frames[0].stamp) / speed - (time.perf_counter() - start)
                    if wait > 0:
                        time.sleep(wait)
                    late += wait < -interval / speed
                t0 = time.perf_counter()
                result = slam.track_rgbd(f.rgb, f.depth_m, f.stamp)
                t_track += time.perf_counter() - t0
                states.append(result.state.name)
        finally:
            slam.shutdown()
        if any(s in OK_STATES for s in states):
            slam.save_trajectory_tum(str(traj_path))
    try:
        traj = read_trajectory(traj_path) if traj_path.is_file() else np.zeros((0, 8))
    finally:
        traj_path.unlink(missing_ok=True)
    return EngineRun(traj, states, 1000 * t_track / max(len(frames), 1), late)


def _interval(frames: Sequence[EngineFrame]) -> float:
    """Median time between frames (s); 1/30 s for a single frame."""
    if len(frames) < 2:
        return 1 / 30
    return float(np.median(np.diff([f.stamp for f in frames])))


def run_dense(frames: Sequence[EngineFrame], camera: Camera) -> EngineRun:
    """Frame-to-frame dense photometric odometry (``cv2.Odometry``, RGB type: intensity
    residuals, depth only to warp) chained from the first frame (identity pose)."""
    settings = cv2.OdometrySettings()
    k = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1]], np.float32)
    settings.setCameraMatrix(k)
    settings.setMaxDepth(DENSE_MAX_DEPTH_M)
    odo = cv2.Odometry(cv2.OdometryType_RGB, settings, cv2.OdometryAlgoType_COMMON)
    pose = np.eye(4)
    rows, states, prev, t_track = [], [], None, 0.0
    for f in frames:
        t0 = time.perf_counter()
        gray = cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY)
        valid = f.static if f.static is not None else np.full(gray.shape, 255, np.uint8)
        cur = cv2.OdometryFrame(image=gray, depth=f.depth_m.astype(np.float32), mask=valid)
        odo.prepareFrame(cur)
        state = "OK"
        if prev is not None:
            ok, rt = odo.compute(cur, prev)  # maps current-camera points into the previous
            if ok and np.isfinite(rt).all():
                pose = pose @ rt
            else:
                state = "LOST"  # keep the previous pose: a constant-position fallback
        t_track += time.perf_counter() - t0
        prev = cur
        states.append(state)
        rows.append(matrix_to_tum(f.stamp, pose))
    return EngineRun(np.array(rows).reshape(-1, 8), states, 1000 * t_track / max(len(frames), 1))


def import_pyorbslam3():
    """``pyorbslam3`` or a one-line ``SlimsegError`` saying how to install it."""
    try:
        import pyorbslam3
    except ImportError:
        raise SlimsegError(
            f"ORB-SLAM3 engine needs the optional pyorbslam3 package: {EXTRA_HINT} "
            "(GPL-3.0), or use --engine dense"
        ) from None
    return pyorbslam3


@contextmanager
def _stdout_to(path: Path | None) -> Iterator[None]:
    """Send file descriptors 1 and 2 (C++ ``std::cout``/``cerr`` included) to ``path`` for
    the block; both are restored afterwards."""
    if path is None:
        yield
        return
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    try:
        with open(path, "ab") as f:
            os.dup2(f.fileno(), 1)
            os.dup2(f.fileno(), 2)
            try:
                yield
            finally:
                sys.stdout.flush()
                sys.stderr.flush()
                os.dup2(saved[0], 1)
                os.dup2(saved[1], 2)
    finally:
        for fd in saved:
            os.close(fd)
