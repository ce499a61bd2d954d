"""``slimseg dynamic --out masks.mcap``: the dynamic masks written back as a ROS recording.

Each mask becomes a ``sensor_msgs/Image`` ``mono8`` (255 = dynamic) on :data:`MASK_TOPIC`
with its source colour frame's header: the bag's own stamp and ``frame_id``, or, for a TUM
folder, the ``rgb.txt`` stamp and :data:`FOLDER_FRAME_ID`; the log time is the stamp. With
``masked``, the colour frame with its dynamic pixels set to black goes on
:data:`MASKED_TOPIC` (``rgb8``). The recording is written atomically
(:class:`~slimseg.data.bag_writer.BagWriter`).
"""

from __future__ import annotations

from pathlib import Path

import cv2

from slimseg.data.bag_reader import Header, stamp_ns
from slimseg.data.bag_sequence import BagSequence
from slimseg.data.bag_writer import BagWriter
from slimseg.data.images import decode_file
from slimseg.data.sequence_source import Sequence
from slimseg.data.tum import mask_name
from slimseg.errors import SlimsegError

MASK_TOPIC = "/slimseg/dynamic_mask"
MASKED_TOPIC = "/slimseg/masked_image"
FOLDER_FRAME_ID = "camera"  # a TUM folder names no frame


def frame_header(seq: Sequence, i: int) -> Header:
    """The header of frame ``i``'s colour image: the bag's, or one made from the stamp."""
    if isinstance(seq, BagSequence):
        return seq.headers[i]
    return Header(stamp_ns(seq.frames[i][0][0]), FOLDER_FRAME_ID)


def write_mask_bag(
    seq: Sequence,
    masks: Path,
    out: Path,
    storage: str | None = None,
    masked: bool = False,
) -> int:
    """Write ``masks/<stamp>.png`` (``uint8 [H, W]``, one per frame of ``seq``) as the bag
    ``out`` (``.bag``, ``.mcap``, or a rosbag2 folder with ``storage``); ``masked``: also the
    masked colour frames. Returns the number of masks written."""
    with BagWriter(out, storage) as bag:
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
    return len(seq)
