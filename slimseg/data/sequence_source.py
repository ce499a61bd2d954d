"""The one place a sequence is opened: a TUM-layout folder, or a ROS recording (a ROS 1
``.bag``, a rosbag2 folder, a bare ``.mcap``) read as one (:mod:`slimseg.data.bag_sequence`).
Both give the same frame interface (``frames``, ``camera``, ``load(i)``, ``fps``,
``describe_camera()``)."""

from __future__ import annotations

from pathlib import Path

from slimseg.data.bag_reader import is_bag
from slimseg.data.bag_sequence import BagOptions, BagSequence
from slimseg.data.tum import TumSequence
from slimseg.errors import SlimsegError

Sequence = TumSequence | BagSequence


def open_sequence(path: str | Path, bag: BagOptions | None = None) -> Sequence:
    """``path`` opened as a :class:`BagSequence` when it is a bag (:func:`is_bag`), else as a
    :class:`TumSequence`; ``bag``: topics and the camera for a bag (a folder refuses them)."""
    if is_bag(path):
        return BagSequence(path, bag or BagOptions())
    given = [] if bag is None else bag.given()
    if given:
        raise SlimsegError(
            f"{', '.join(given)}: for a ROS bag --sequence only, and {path} is a TUM folder "
            "(its camera.yaml gives the intrinsics)"
        )
    return TumSequence(path)
