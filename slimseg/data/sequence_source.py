"""The one place a sequence is opened: a TUM-layout folder, or a ROS recording (a ROS 1
``.bag``, a rosbag2 folder, a bare ``.mcap``) read as one (:mod:`slimseg.data.bags.sequence`).
Both are a :class:`~slimseg.data.frame_source.FrameSource`; open one with ``with`` so that a
recording's file is closed when the command is done with it."""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from pathlib import Path
from typing import ParamSpec, TypeVar

from slimseg.data.bags.reader import is_bag
from slimseg.data.bags.sequence import BagOptions, BagSequence
from slimseg.data.frame_source import FrameSource
from slimseg.data.tum import TumSequence
from slimseg.errors import SlimsegError

P = ParamSpec("P")
R = TypeVar("R")


def open_sequence(path: str | Path, bag: BagOptions | None = None) -> FrameSource:
    """``path`` opened as a :class:`BagSequence` when it is a bag (:func:`is_bag`), else as a
    :class:`TumSequence`; ``bag``: topics and the camera for a bag (a folder refuses them).
    Use it as ``with open_sequence(path) as seq:``."""
    if is_bag(path):
        return BagSequence(path, bag or BagOptions())
    given = [] if bag is None else bag.given()
    if given:
        raise SlimsegError(
            f"{', '.join(given)}: for a ROS bag --sequence only, and {path} is a TUM folder "
            "(its camera.yaml gives the intrinsics)"
        )
    return TumSequence(path)


def opens_sequence(run: Callable[P, R]) -> Callable[P, R]:
    """Decorate a function whose ``sequence`` argument is a folder or recording path or an
    opened :class:`FrameSource`: a path is opened for the call (:func:`open_sequence`) and
    closed when it returns or raises; a source passed in is used as is and left open (whoever
    opened it closes it)."""
    signature = inspect.signature(run)
    if "sequence" not in signature.parameters:
        raise TypeError(f"{run.__qualname__} has no 'sequence' parameter")

    @functools.wraps(run)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        bound = signature.bind(*args, **kwargs)
        given = bound.arguments["sequence"]
        if not isinstance(given, str | Path):
            return run(*args, **kwargs)
        with open_sequence(given) as seq:
            bound.arguments["sequence"] = seq
            return run(*bound.args, **bound.kwargs)

    return wrapper
