"""What every opened RGB-D sequence gives the commands that read it: the :class:`FrameSource`
protocol, which a TUM-layout folder (:class:`~slimseg.data.tum.TumSequence`) and a ROS
recording (:class:`~slimseg.data.bags.sequence.BagSequence`) both implement, and
:class:`PairedFrames`, the behaviour they share (frame count, rate, the intrinsics line, the
index check, the depth-unit check, closing as a context manager), and the types both carry:
the :class:`Camera` intrinsics and the :class:`Associations` of colour and depth frames
(built by :func:`slimseg.data.tum.associate`).

Open a source with :func:`slimseg.data.sequence_source.open_sequence` inside ``with``: a bag
holds its file open until :meth:`FrameSource.close` (a folder holds nothing, so closing it is
free).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, Self

import numpy as np

from slimseg.utils.text import printable

#: one frame: ``rgb uint8 [H, W, 3]``, ``depth_m float32 [H, W]`` (0: no depth), colour stamp s
Frame = tuple[np.ndarray, np.ndarray, float]
#: plausible median depth of a frame (m): outside it, the depth's units are misread
DEPTH_RANGE_M = (0.05, 100.0)
#: one entry of a frame list: ``(stamp s, file name or message reference)``
Stamped = tuple[float, str]


class Associations(list[tuple[Stamped, Stamped]]):
    """``associate`` result: a list of ``((t_rgb, rgb_path), (t_depth, depth_path))`` pairs
    sorted by RGB time, plus how many RGB and depth entries found no partner."""

    unmatched_rgb: int = 0
    unmatched_depth: int = 0


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics in px; ``depth_scale``: stored depth units per metre."""

    fx: float
    fy: float
    cx: float
    cy: float
    depth_scale: float

    @property
    def pinhole(self) -> tuple[float, float, float, float]:
        """``(fx, fy, cx, cy)`` px, as ``slimseg.Masker(camera=)`` and the chain take them."""
        return (self.fx, self.fy, self.cx, self.cy)


class FrameSource(Protocol):
    """An opened RGB-D sequence. ``frames``: the associated ``((t_rgb, rgb), (t_depth, depth))``
    pairs; ``camera``: the intrinsics, ``camera_source`` where they came from; ``root``: the
    folder or recording."""

    root: Path
    frames: Associations
    camera: Camera
    camera_source: str

    @property
    def fps(self) -> float:
        """Frames per second from the colour stamps."""
        ...

    def __len__(self) -> int: ...

    def load(self, i: int) -> Frame:
        """Frame ``i`` (negative counts from the end); ``IndexError`` out of range."""
        ...

    def describe_camera(self) -> str:
        """One line for a command: the intrinsics in use and where they came from."""
        ...

    def close(self) -> None:
        """Release what the source holds open; it cannot load frames afterwards."""
        ...

    def __enter__(self) -> Self: ...

    def __exit__(self, *exc: object) -> None: ...


def frame_rate(frames: list) -> float:
    """Frames per second from the median interval of the colour stamps of ``frames``
    (``[((t_rgb, rgb), (t_depth, depth)), ...]``, a sequence's associations); 30 for one."""
    stamps = np.array([t for (t, _), _ in frames])
    return float(1.0 / np.median(np.diff(stamps))) if len(stamps) > 1 else 30.0


def implausible_median_depth(depth: np.ndarray) -> float | None:
    """The median valid depth (m) of ``depth`` when it lies outside :data:`DEPTH_RANGE_M`
    (millimetres read as TUM's units, a float image in millimetres), else None."""
    valid = depth[depth > 0]
    if not len(valid):
        return None
    median = float(np.median(valid))
    lo, hi = DEPTH_RANGE_M
    return None if lo <= median <= hi else median


class PairedFrames:
    """The part of a :class:`FrameSource` every kind shares. A subclass sets ``root``,
    ``frames``, ``camera`` and ``camera_source`` and implements ``load``; one that holds a file
    open overrides :meth:`close`."""

    root: Path
    frames: Associations
    camera: Camera
    camera_source: str

    def camera_origin(self) -> str:
        """Where the intrinsics came from, as :meth:`describe_camera` says it."""
        return self.camera_source

    def describe_camera(self) -> str:
        """One line for a command: the intrinsics in use and where they came from (text from
        a recording or a folder name escaped for the terminal)."""
        c = self.camera
        return printable(
            f"intrinsics: fx {c.fx}, fy {c.fy}, cx {c.cx}, cy {c.cy} from {self.camera_origin()}"
        )

    @property
    def fps(self) -> float:
        """Frame rate from the median colour-frame interval (30 for a single frame)."""
        return frame_rate(self.frames)

    def __len__(self) -> int:
        return len(self.frames)

    def frame_index(self, i: int) -> int:
        """``i`` as an index into ``frames`` (negative counts from the end); ``IndexError``
        out of range."""
        n = len(self.frames)
        if not -n <= i < n:
            raise IndexError(f"frame {i} out of range (sequence has {n})")
        return i % n

    def close(self) -> None:
        """Nothing to release (a folder's files are opened and closed frame by frame)."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
