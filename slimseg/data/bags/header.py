"""The bottom of the bag readers: the message roles slimseg reads (ROS 2 type names), a
message's :class:`Header` (its stamp, signed and exact to the nanosecond), and
:func:`header_of`, which reads a ROS message's ``std_msgs/Header`` straight from its bytes.

Everything above it (:mod:`~slimseg.data.bags.foxglove_messages`,
:mod:`~slimseg.data.bags.mcap_file`, :mod:`~slimseg.data.bags.reader`) imports from here and
never the other way round (the ``slimseg.data.bags readers`` contract in ``pyproject.toml``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from slimseg.errors import SlimsegError

NS_PER_S = 1_000_000_000
DAMAGED = "a truncated or damaged recording: record it again, or repair it with its reindex tool"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POSE = "geometry_msgs/msg/PoseStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
TF = "tf2_msgs/msg/TFMessage"


def stamp_text(ns: int) -> str:
    """``ns`` as signed decimal seconds with all nine digits: ``-4966666667`` →
    ``"-4.966666667"`` (the sign applies to the whole value, never to one part)."""
    whole, frac = divmod(abs(ns), NS_PER_S)
    return f"{'-' if ns < 0 else ''}{whole}.{frac:09d}"


@dataclass(frozen=True)
class Header:
    """A message's ``std_msgs/Header``: stamp (integer ns and seconds) and ``frame_id``."""

    ns: int
    frame_id: str

    @property
    def seconds(self) -> float:
        """The stamp in seconds, parsed from its decimal form (the same float a TUM list's
        ``sec.nsec`` text gives); a stamp before 1970 keeps its order (-4.97 s > -5.03 s)."""
        return float(stamp_text(self.ns))


# the stamps each kind of recording can hold, as [first, last] ns: log times are unsigned
# 64-bit ns (MCAP) or signed 64-bit (SQLite), ROS 1 stamps unsigned 32-bit seconds, ROS 2
# header stamps signed 32-bit seconds; 0 (1970) is the first a log time can be
STAMP_RANGES = {
    "ros1": (0, (1 << 32) * NS_PER_S - 1),
    "ros2": (0, (1 << 31) * NS_PER_S - 1),
    "foxglove": (0, (1 << 63) - 1),
}


def check_stamp(ns: int, kind: str, where: str) -> None:
    """``SlimsegError`` naming ``where`` (the output) when ``ns`` is not a stamp a ``kind``
    recording (a key of :data:`STAMP_RANGES`) can hold as its log time and header stamp: a
    stamp before 1970 cannot be written, only refused; it is never wrapped or clipped."""
    lo, hi = STAMP_RANGES[kind]
    if not lo <= ns <= hi:
        raise SlimsegError(
            f"{where}: stamp {stamp_text(ns)} s cannot be written to a {kind} recording (it "
            f"holds {stamp_text(lo)} to {stamp_text(hi)} s: log times start at 1970); "
            "re-stamp the input, or write a TUM folder instead"
        )


def stamp_ns(seconds: float) -> int:
    """A TUM stamp (s, microseconds as written in ``rgb.txt``) as integer nanoseconds, through
    its 6-decimal text so no float rounding creeps in."""
    whole, _, frac = f"{seconds:.6f}".partition(".")
    sign = -1 if whole.startswith("-") else 1
    return int(whole) * NS_PER_S + sign * int(frac) * 1000


def header_of(raw: bytes | memoryview, cdr: bool) -> Header:
    """The leading ``Header`` of a serialized message (ROS 1: ``seq, sec, nsec, frame_id``;
    CDR: 4-byte encapsulation, ``sec, nanosec, frame_id``; ROS 2's ``sec`` is signed). Raises
    ``ValueError`` when the bytes are too short to hold one."""
    buf = memoryview(raw)
    if len(buf) < 16:
        raise ValueError("message shorter than a header")
    if cdr:
        endian = "<" if buf[1] & 1 else ">"  # representation 0x0001 = CDR_LE, 0x0000 = CDR_BE
        sec, nsec, n = struct.unpack_from(f"{endian}iII", buf, 4)
        name = bytes(buf[16 : 16 + max(n - 1, 0)])
    else:
        _, sec, nsec, n = struct.unpack_from("<IIII", buf, 0)
        name = bytes(buf[16 : 16 + n])
    if len(name) != max(n - (1 if cdr else 0), 0) or nsec >= NS_PER_S:
        raise ValueError("malformed header")
    return Header(sec * NS_PER_S + nsec, name.decode("utf-8", "replace"))
