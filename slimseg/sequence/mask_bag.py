"""``slimseg dynamic --out masks.mcap``: the dynamic masks written back as a recording, in the
source's own profile.

A ROS source (or a TUM folder): each mask becomes a ``sensor_msgs/Image`` ``mono8`` (255 =
dynamic) on :data:`MASK_TOPIC` with its source colour frame's header: the bag's own stamp and
``frame_id``, or, for a TUM folder, the ``rgb.txt`` stamp and :data:`FOLDER_FRAME_ID`; the log
time is the stamp. With ``masked``, the colour frame with its dynamic pixels set to black goes on
:data:`MASKED_TOPIC` (``rgb8``). Written by :class:`~slimseg.data.bags.writer.BagWriter`.

A Foxglove source (protobuf or JSON schemas) written to ``.mcap``: the same topics as
``foxglove.RawImage`` (``mono8``, ``rgb8``), and the judged objects of each frame as
``foxglove.ImageAnnotations`` on :data:`OBJECTS_TOPIC` (a box per object, labelled with its
track id, class and moving probability; red where the probability is at least one half), all at
the source stamps (:class:`~slimseg.data.bags.foxglove_writer.FoxgloveWriter`). Both are written
atomically.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from slimseg.data.bags.foxglove_writer import FoxgloveWriter
from slimseg.data.bags.header import Header, stamp_ns
from slimseg.data.bags.sequence import BagSequence
from slimseg.data.bags.writer import BagWriter
from slimseg.data.frame_source import FrameSource
from slimseg.data.images import decode_file
from slimseg.data.tum import mask_name
from slimseg.errors import SlimsegError
from slimseg.objects import Objects

MASK_TOPIC = "/slimseg/dynamic_mask"
MASKED_TOPIC = "/slimseg/masked_image"
OBJECTS_TOPIC = "/slimseg/dynamic_objects"
FOLDER_FRAME_ID = "camera"  # a TUM folder names no frame
MOVING = (0.9, 0.1, 0.1, 1.0)  # RGBA of an object at least half likely to move
STILL = (0.1, 0.4, 0.9, 1.0)


@dataclass(frozen=True)
class FrameBoxes:
    """The objects of one frame as drawn: ``boxes float32 [M, 4]`` xyxy px, a label and a
    colour each."""

    boxes: np.ndarray
    labels: list[str]
    colours: list[tuple[float, float, float, float]]


def object_labels(objects: Objects, names: list[str]) -> list[str]:
    """``#<track id> <class> p <moving probability>`` per object (no ``#`` part for an
    untracked detection)."""
    out = []
    for k in range(len(objects)):
        cls = int(objects.classes[k])
        name = names[cls] if 0 <= cls < len(names) else str(cls)
        tid = int(objects.track_ids[k])
        out.append(("" if tid < 0 else f"#{tid} ") + f"{name} p {float(objects.mobility[k]):.2f}")
    return out


def frame_boxes(objects: Objects, names: list[str]) -> FrameBoxes:
    """``objects`` as drawn: labelled by :func:`object_labels`, red when at least half likely
    to move."""
    colours = [MOVING if float(p) >= 0.5 else STILL for p in objects.mobility]
    boxes = np.asarray(objects.boxes, np.float32).reshape(-1, 4)
    return FrameBoxes(boxes, object_labels(objects, names), colours)


def frame_header(seq: FrameSource, i: int) -> Header:
    """The header of frame ``i``'s colour image: the bag's, or one made from the stamp."""
    if isinstance(seq, BagSequence):
        return seq.headers[i]
    return Header(stamp_ns(seq.frames[i][0][0]), FOLDER_FRAME_ID)


def writes_foxglove(seq: FrameSource, out: Path, storage: str | None) -> bool:
    """Whether the masks of ``seq`` go back as Foxglove messages: a Foxglove source, a bare
    ``.mcap`` output."""
    foxglove = isinstance(seq, BagSequence) and seq.profile.startswith("foxglove")
    return foxglove and storage is None and out.suffix.lower() == ".mcap"


def write_mask_bag(
    seq: FrameSource,
    masks: Path,
    out: Path,
    storage: str | None = None,
    masked: bool = False,
    boxes: list[FrameBoxes] | None = None,
) -> int:
    """Write ``masks/<stamp>.png`` (``uint8 [H, W]``, one per frame of ``seq``) as the
    recording ``out`` (``.bag``, ``.mcap``, or a rosbag2 folder with ``storage``); ``masked``:
    also the masked colour frames; ``boxes``: per frame, the objects (Foxglove output only).
    Returns the number of masks written."""
    foxglove = writes_foxglove(seq, out, storage)
    with FoxgloveWriter(out) if foxglove else BagWriter(out, storage) as bag:
        for i in range(len(seq)):
            stamp = seq.frames[i][0][0]
            path = masks / mask_name(stamp)
            mask = decode_file(path, cv2.IMREAD_GRAYSCALE)
            if mask is None:
                raise SlimsegError(f"missing or unreadable dynamic mask {path}")
            head = frame_header(seq, i)
            bag.write_image(MASK_TOPIC, head, mask, "mono8")
            if masked:
                rgb = seq.load(i)[0]
                bag.write_image(MASKED_TOPIC, head, rgb * (mask[..., None] == 0), "rgb8")
            if foxglove and boxes is not None:
                b = boxes[i]
                bag.write_boxes(OBJECTS_TOPIC, head, b.boxes, b.labels, b.colours)
    return len(seq)
