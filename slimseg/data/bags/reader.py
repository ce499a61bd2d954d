"""ROS recordings opened for reading: a ROS 1 ``.bag``, a rosbag2 folder (``metadata.yaml`` with
MCAP or SQLite storage) or a bare ``.mcap`` file, through the pure-Python ``rosbags`` library
(the ``slimseg[ros]`` extra, imported here only when a bag is opened; no ROS installation).

:class:`BagFile` lists the topics with their message types and yields raw messages in log-time
order; :func:`header_of` reads a message's ``std_msgs/Header`` straight from its bytes (both
wire formats put it first), so indexing a bag of images does not copy a single pixel;
:meth:`BagFile.decode` turns a raw message into the library's message object. Every failure of
the underlying reader (a truncated or corrupt file, an unknown storage) becomes a one-line
``SlimsegError`` naming the bag.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from slimseg.data.bags.mcap_crc import check_data_crc
from slimseg.errors import SlimsegError
from slimseg.utils.extras import install_command
from slimseg.utils.input_files import check_regular

log = logging.getLogger(__name__)

BAG_SUFFIXES = (".bag", ".mcap")
INSTALL_HINT = install_command("ros")
DAMAGED = "a truncated or damaged recording: record it again, or repair it with its reindex tool"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POSE = "geometry_msgs/msg/PoseStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
TF = "tf2_msgs/msg/TFMessage"


def is_bag(path: str | Path) -> bool:
    """True for what :class:`BagFile` opens: a ``.bag`` / ``.mcap`` path, or a folder holding a
    rosbag2 ``metadata.yaml``."""
    p = Path(path)
    return p.suffix.lower() in BAG_SUFFIXES or (p.is_dir() and (p / "metadata.yaml").is_file())


def require_rosbags(path: str | Path) -> None:
    """``SlimsegError`` naming the extra to install when ``rosbags`` is missing."""
    try:
        import rosbags  # noqa: F401
    except ImportError:
        raise SlimsegError(
            f"{path} is a ROS bag; reading and writing bags needs the rosbags library: "
            f"{INSTALL_HINT}"
        ) from None


@dataclass(frozen=True)
class Header:
    """A message's ``std_msgs/Header``: stamp (integer ns and seconds) and ``frame_id``."""

    ns: int
    frame_id: str

    @property
    def seconds(self) -> float:
        """The stamp in seconds, parsed from its decimal form (the same float a TUM list's
        ``sec.nsec`` text gives)."""
        return float(f"{self.ns // 1_000_000_000}.{self.ns % 1_000_000_000:09d}")


def stamp_ns(seconds: float) -> int:
    """A TUM stamp (s, microseconds as written in ``rgb.txt``) as integer nanoseconds, through
    its 6-decimal text so no float rounding creeps in."""
    whole, _, frac = f"{seconds:.6f}".partition(".")
    sign = -1 if whole.startswith("-") else 1
    return int(whole) * 1_000_000_000 + sign * int(frac) * 1000


def header_of(raw: bytes | memoryview, cdr: bool) -> Header:
    """The leading ``Header`` of a serialized message (ROS 1: ``seq, sec, nsec, frame_id``;
    CDR: 4-byte encapsulation, ``sec, nanosec, frame_id``). Raises ``ValueError`` when the bytes
    are too short to hold one."""
    buf = memoryview(raw)
    if cdr:
        if len(buf) < 16:
            raise ValueError("message shorter than a header")
        endian = "<" if buf[1] & 1 else ">"  # representation 0x0001 = CDR_LE, 0x0000 = CDR_BE
        sec, nsec, n = struct.unpack_from(f"{endian}iII", buf, 4)
        name = bytes(buf[16 : 16 + max(n - 1, 0)])
    else:
        if len(buf) < 16:
            raise ValueError("message shorter than a header")
        _, sec, nsec, n = struct.unpack_from("<IIII", buf, 0)
        name = bytes(buf[16 : 16 + n])
    if len(name) != max(n - (1 if cdr else 0), 0) or nsec >= 1_000_000_000:
        raise ValueError("malformed header")
    return Header(sec * 1_000_000_000 + nsec, name.decode("utf-8", "replace"))


class BagFile:
    """An open recording (use as a context manager).

    ``topics``: ``{topic: message type}`` (``"sensor_msgs/msg/Image"`` spelling for both ROS
    generations); ``cdr``: True for rosbag2 / MCAP (CDR), False for ROS 1."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise SlimsegError(f"bag {self.path} does not exist")
        check_inputs(self.path)  # regular files only, MCAP data-section CRCs: before any open
        require_rosbags(self.path)
        from rosbags.typesys import Stores, get_typestore

        self.cdr = self.path.suffix.lower() != ".bag"
        self._store = get_typestore(Stores.ROS2_HUMBLE if self.cdr else Stores.ROS1_NOETIC)
        if not self.cdr:  # ROS 1's store lacks tf2's message; its definition is one line
            from rosbags.typesys import get_types_from_msg

            self._store.register(
                get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF)
            )
        self._mcap = self._open_mcap() if self.path.suffix.lower() == ".mcap" else None
        self.topics: dict[str, str] = {}
        self.held: dict[str, str] = {}  # the types as an MCAP of any profile names them
        if self._mcap is not None:
            self._reader = self._mcap
            self.cdr = all(c.message_encoding != "ros1" for c in self._mcap.channels)
            for ch in self._mcap.channels:
                self.topics.setdefault(ch.topic, ch.role or ch.kind)
                self.held.setdefault(ch.topic, ch.kind)
            return
        try:
            self._reader = self._open()
        except SlimsegError:
            raise
        except Exception as e:  # the third-party parser's errors on a damaged file, all of them
            raise SlimsegError(f"cannot read bag {self.path}: {_why(e)} ({DAMAGED})") from None
        self._connections = list(self._reader.connections)
        for c in self._connections:
            self.topics.setdefault(c.topic, c.msgtype)

    def _open_mcap(self) -> object:
        """A :class:`~slimseg.data.bags.mcap_file.McapFile` for an MCAP file rosbags does not read
        (any profile but ``ros2``: ``ros1``, Foxglove schemas); None for a ``ros2`` one, or
        one whose summary does not parse (rosbags' reader then names the damage)."""
        from slimseg.data.bags import mcap_file

        try:
            import mcap  # noqa: F401
        except ImportError:
            raise SlimsegError(
                f"{self.path} is an MCAP file; reading it needs the mcap and protobuf "
                f"packages: {INSTALL_HINT}"
            ) from None
        held = mcap_file.mcap_channels(self.path)
        if held is None or mcap_file.rosbags_reads(*held):
            return None
        mcap_file.refuse_unreadable(self.path, *held)
        return mcap_file.McapFile(self.path, held[1])

    def _open(self) -> object:
        if self.path.is_dir():
            if not (self.path / "metadata.yaml").is_file():
                raise SlimsegError(
                    f"bag folder {self.path} has no metadata.yaml: not a rosbag2 recording"
                )
            from rosbags.rosbag2 import Reader
        elif self.path.suffix.lower() == ".mcap":
            from rosbags.rosbag2.storage_mcap import McapReader as Reader
        else:
            from rosbags.rosbag1 import Reader
        reader = Reader(self.path)
        reader.open()
        return reader

    def profile(self, topic: str) -> str:
        """How ``topic`` is encoded: ``ros1``, ``ros2``, ``foxglove protobuf`` or ``foxglove
        JSON``."""
        if self._mcap is not None:
            return self._mcap.profile(topic)
        return "ros2" if self.cdr else "ros1"

    def __enter__(self) -> BagFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` released the file."""
        return self._reader is None

    def close(self) -> None:
        """Release the file (once; a second call does nothing)."""
        if self._reader is not None:
            try:
                self._reader.close()
            except Exception:  # closing a damaged file: nothing left to report
                log.debug("closing %s failed", self.path, exc_info=True)
            self._reader = None

    def messages(
        self, topics: list[str], start_ns: int | None = None
    ) -> Iterator[tuple[str, int, bytes]]:
        """``(topic, log time ns, raw bytes)`` of ``topics`` in log-time order, from
        ``start_ns`` on (None: the start). A damaged file raises ``SlimsegError``."""
        try:
            if self._mcap is not None:
                yield from self._mcap.messages(topics, start_ns)
                return
            conns = [c for c in self._connections if c.topic in topics]
            if not conns:
                return
            for conn, t, raw in self._reader.messages(connections=conns, start=start_ns):
                yield conn.topic, t, raw
        except Exception as e:  # the third-party parser's errors on a damaged file, all of them
            raise SlimsegError(f"cannot read bag {self.path}: {_why(e)} ({DAMAGED})") from None

    def decode(self, raw: bytes, msgtype: str, topic: str) -> object:
        """The message object of ``raw`` (a ``msgtype`` message on ``topic``)."""
        try:
            if self._mcap is not None:
                return self._mcap.decode(raw, topic)
            if self.cdr:
                return self._store.deserialize_cdr(raw, msgtype)
            return self._store.deserialize_ros1(raw, msgtype)
        except Exception as e:  # the third-party deserializer's errors, all of them
            raise SlimsegError(
                f"bag {self.path}: a {msgtype} message on {topic} does not decode: {_why(e)}"
            ) from None

    def header(self, raw: bytes, topic: str) -> Header:
        """:func:`header_of` with the bag's wire format, ``SlimsegError`` naming the topic."""
        try:
            if self._mcap is not None:
                return self._mcap.header(raw, topic)
            return header_of(raw, self.cdr)
        except (ValueError, struct.error) as e:
            raise SlimsegError(
                f"bag {self.path}: a message on {topic} has no header: {e}"
            ) from None


def check_inputs(path: Path) -> None:
    """Before a recording is opened: ``path`` (or, for a rosbag2 folder, its
    ``metadata.yaml`` and storage files) must be regular files (a FIFO or a device would
    block or never end) and each MCAP's recorded data-section CRC must match its bytes;
    ``SlimsegError`` naming the file otherwise."""
    files = sorted(p for p in path.iterdir() if p.name == "metadata.yaml" or p.suffix in
                   (".mcap", ".db3")) if path.is_dir() else [path]  # fmt: skip
    for f in files:
        check_regular(f, "bag" if f == path else "bag file")
        if f.suffix.lower() == ".mcap":
            check_data_crc(f)


def _why(e: Exception) -> str:
    """One line: the exception's message (or its type when it has none)."""
    text = " ".join(" ".join(str(a) for a in e.args).split()) or type(e).__name__
    return text[:300]
