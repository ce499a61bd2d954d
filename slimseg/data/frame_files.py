"""Frames from what a user points a command at: a folder of images, one image, a video or a
ROS bag's colour topic (:func:`open_source`), with the image suffixes the commands read
(:data:`IMAGE_SUFFIXES`, one home for ``predict`` and the INT8 calibration images)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from slimseg.data.bags.colour_stream import BagColour
from slimseg.data.bags.reader import is_bag
from slimseg.data.images import read_rgb
from slimseg.data.problems import ImageProblem
from slimseg.errors import SlimsegError
from slimseg.utils.input_files import check_regular
from slimseg.utils.outputs import unique_stems

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


def image_frames(paths: list[Path]) -> Iterator[tuple[str, str, np.ndarray | None]]:
    """``(stem, source path, RGB)`` per image; stems never collide (a.png and a.jpg: ``a_png``,
    ``a_jpg``; :func:`slimseg.utils.outputs.unique_stems`). An image that cannot be read comes
    as ``(stem, "<path>: <why>", None)`` (the skip report names both)."""
    stems = unique_stems([p.stem for p in paths], [p.suffix for p in paths])
    for path, stem in zip(paths, stems, strict=True):
        try:
            image, source = read_rgb(path), str(path)
        except ImageProblem as e:
            image, source = None, str(e)
        yield stem, source, image


def video_frames(path: Path) -> Iterator[tuple[str, str, np.ndarray | None]]:
    """``(frame_NNNNNN, video path, RGB)`` per frame OpenCV reads from the video."""
    cap = cv2.VideoCapture(str(path))
    try:
        index = 0
        while True:
            ok, bgr = cap.read()
            if not ok:
                break
            yield f"frame_{index:06d}", str(path), cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            index += 1
    finally:
        cap.release()


def open_source(
    source: str | Path, rgb_topic: str | None = None
) -> tuple[Iterator[tuple[str, str, np.ndarray | None]], int, bool]:
    """Frames of ``source`` as ``(stem, path, RGB or None if unreadable)``, their count (0:
    unknown) and whether they come from a video (a bag's colour topic, ``rgb_topic`` or the
    only one, gives stems of its stamps)."""
    path = Path(source)
    if not path.exists():
        raise SlimsegError(f"{path}: no such file or folder")
    if is_bag(path):
        bag = BagColour(path, rgb_topic)
        return bag.frames(), len(bag.stamps), False
    if rgb_topic is not None:
        raise SlimsegError(f"--rgb-topic applies to a ROS bag --source; {path} is not one")
    if path.is_dir():
        images = sorted(
            p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
        )
        if not images:
            raise SlimsegError(f"{path}: no {'/'.join(IMAGE_SUFFIXES)} images in this folder")
        return image_frames(images), len(images), False
    check_regular(path, "--source")  # a FIFO named .mp4 or .png would block forever
    if path.suffix.lower() in IMAGE_SUFFIXES:
        return image_frames([path]), 1, False
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise SlimsegError(
                f"{path}: neither an image ({'/'.join(IMAGE_SUFFIXES)}) nor a video OpenCV can open"
            )
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        cap.release()
    return video_frames(path), max(count, 0), True
