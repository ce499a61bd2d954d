"""Values a sequence's files give, checked where they are read: poses (finite, a usable
quaternion), intrinsics (finite pixels in a plausible range) and frames (one size per
sequence; a warning for a frame without depth). Each refusal names the file and line, the bag
message or the frame."""

from __future__ import annotations

import logging

import numpy as np

from slimseg.errors import SlimsegError

log = logging.getLogger(__name__)

QUATERNION_NORM = (0.5, 2.0)  # accepted norms of a trajectory's quaternion (a unit one: 1)


def check_pose(row: list[float] | np.ndarray, where: str, shown: str = "") -> None:
    """``SlimsegError`` naming ``where`` (a file and line, a bag message) unless the TUM row
    ``t tx ty tz qx qy qz qw`` is finite and its quaternion's norm lies in
    :data:`QUATERNION_NORM` (a unit rotation, written with a usable precision; the row is
    kept as written, and the scorer normalises it)."""
    vals = np.asarray(row, np.float64)
    if not np.all(np.isfinite(vals)):
        raise SlimsegError(f"{where}: a value is not finite (nan or inf){shown}")
    norm = float(np.linalg.norm(vals[4:]))
    low, high = QUATERNION_NORM
    if not low <= norm <= high:
        q = " ".join(f"{v:g}" for v in vals[4:])
        raise SlimsegError(
            f"{where}: quaternion qx qy qz qw = {q} has norm {norm:.3g}, not a rotation (a "
            f"unit quaternion's norm is 1; {low:g} to {high:g} is accepted){shown}"
        )


INTRINSICS_RANGE = (1.0, 1e5)  # px: fx, fy, cx, cy of any camera a SLAM front end runs on


def check_intrinsics(values: dict[str, float], where: str) -> None:
    """``SlimsegError`` naming ``where`` and the first value (of ``fx fy cx cy``) that is not a
    finite number in :data:`INTRINSICS_RANGE` (pixels; ``fx = 1e-300`` or ``1e12`` is no
    camera: every back-projection would overflow or vanish)."""
    low, high = INTRINSICS_RANGE
    for name, v in values.items():
        if not (np.isfinite(v) and low <= v <= high):
            raise SlimsegError(
                f"{where}: {name} = {v:g} px is outside {low:g}..{high:g}; give the camera's "
                "calibrated intrinsics (pixels)"
            )


class FrameChecks:
    """What every frame of one sequence must share, checked as frames load: the size of the
    first frame loaded (a frame of another size is refused, naming it), and valid depth (the
    first frame without any, all 0 or NaN, is named in a warning; :attr:`no_depth` lists all
    of them)."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.size: tuple[int, int] | None = None
        self.first: str = ""
        self.no_depth: set[str] = set()

    def check(self, size: tuple[int, ...], depth: np.ndarray, frame: str) -> None:
        """``size``: the frame's ``(H, W)``; ``depth``: its metres (0: invalid)."""
        hw = (int(size[0]), int(size[1]))
        if self.size is None:
            self.size, self.first = hw, frame
        elif hw != self.size:
            raise SlimsegError(
                f"{frame}: {hw[1]}x{hw[0]} px, but {self.first} is {self.size[1]}x"
                f"{self.size[0]}: every frame of a sequence has one size"
            )
        if frame not in self.no_depth and not np.any(depth > 0):
            if not self.no_depth:
                log.warning(
                    "%s: no valid depth (all 0 or NaN); the depth rules skip such frames",
                    frame,
                )
            self.no_depth.add(frame)
