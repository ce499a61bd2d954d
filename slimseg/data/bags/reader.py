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
from collections.abc import Iterator
from pathlib import Path

from slimseg.data.bags.header import (
    DAMAGED,
    TF,
    Header,
    header_of,
)
from slimseg.data.bags.mcap_crc import check_mcap
from slimseg.errors import SlimsegError
from slimseg.utils.decode_boundary import decoding, reason
from slimseg.utils.extras import install_command
from slimseg.utils.input_files import check_regular
from slimseg.utils.text import printable

log = logging.getLogger(__name__)

BAG_SUFFIXES = (".bag", ".mcap")
INSTALL_HINT = install_command("ros")


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


class BagFile:
    """An open recording (use as a context manager).

    ``topics``: ``{topic: message type}`` (``"sensor_msgs/msg/Image"`` spelling for both ROS
    generations); ``cdr``: True for rosbag2 / MCAP (CDR), False for ROS 1."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise SlimsegError(f"bag {self.path} does not exist")
        check_inputs(self.path)  # regular files only, every MCAP checksum: before any open
        require_rosbags(self.path)
        from rosbags.typesys import Stores, get_typestore

        self.cdr = self.path.suffix.lower() != ".bag"
        self._store = get_typestore(Stores.ROS2_HUMBLE if self.cdr else Stores.ROS1_NOETIC)
        if not self.cdr:  # ROS 1's store lacks tf2's message; its definition is one line
            from rosbags.typesys import get_types_from_msg

            self._store.register(
                get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF)
            )
        self._mcap = None
        if self.path.suffix.lower() == ".mcap":
            with decoding(f"cannot read bag {self.path} ({DAMAGED})"):
                self._mcap = self._open_mcap()
        self.topics: dict[str, str] = {}
        self.listed: dict[str, int | None] = {}  # messages per topic as the index lists them
        self.held: dict[str, str] = {}  # the types as an MCAP of any profile names them
        if self._mcap is not None:
            self._reader = self._mcap
            self.cdr = all(c.message_encoding != "ros1" for c in self._mcap.channels)
            for ch in self._mcap.channels:
                self.topics.setdefault(ch.topic, ch.role or ch.kind)
                self.held.setdefault(ch.topic, ch.kind)
                known = ch.count is not None and self.listed.get(ch.topic, 0) is not None
                # no statistics: the topic's count is not known (None), and not checked
                self.listed[ch.topic] = self.listed.get(ch.topic, 0) + ch.count if known else None
            return
        try:
            self._reader = self._open()
        except SlimsegError:
            raise
        except Exception as e:  # the third-party parser's errors on a damaged file, all of them
            raise SlimsegError(f"cannot read bag {self.path}: {reason(e)} ({DAMAGED})") from None
        self._connections = list(self._reader.connections)
        for c in self._connections:
            self.topics.setdefault(c.topic, c.msgtype)
            self.listed[c.topic] = self.listed.get(c.topic, 0) + int(c.msgcount or 0)

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
        ``start_ns`` on (None: the start). A damaged file raises ``SlimsegError``; so does a
        whole pass that reads another number of messages on a topic than the recording's
        index or summary lists (a chunk or row lost without a trace)."""
        counts = dict.fromkeys(topics, 0)
        try:
            for topic, t, raw in self._raw_messages(topics, start_ns):
                counts[topic] += 1
                yield topic, t, raw
        except SlimsegError:
            raise
        except Exception as e:  # the third-party parser's errors on a damaged file, all of them
            raise SlimsegError(f"cannot read bag {self.path}: {reason(e)} ({DAMAGED})") from None
        if start_ns is None:
            for topic, n in counts.items():
                listed = self.listed.get(topic)
                if listed and n != listed:  # 0 or None: nothing listed to check against
                    raise SlimsegError(
                        f"cannot read bag {self.path}: {n} messages on {printable(topic)} "
                        f"read where its index lists {listed} ({DAMAGED})"
                    )

    def _raw_messages(
        self, topics: list[str], start_ns: int | None
    ) -> Iterator[tuple[str, int, bytes]]:
        if self._mcap is not None:
            yield from self._mcap.messages(topics, start_ns)
            return
        conns = [c for c in self._connections if c.topic in topics]
        if conns:
            for conn, t, raw in self._reader.messages(connections=conns, start=start_ns):
                yield conn.topic, t, raw

    def decode(self, raw: bytes, msgtype: str, topic: str, index: int | None = None) -> object:
        """The message object of ``raw`` (a ``msgtype`` message on ``topic``; ``index``: its
        place among the topic's messages, for the error), every field checked against its
        schema; any decoder's error is one ``SlimsegError`` line naming the message."""
        with decoding(f"bag {self.path}: {_message(index, topic)} ({msgtype}) does not decode"):
            if self._mcap is not None:
                return self._mcap.decode(raw, topic)
            if self.cdr:
                return self._store.deserialize_cdr(raw, msgtype)
            return self._store.deserialize_ros1(raw, msgtype)

    def header(self, raw: bytes, topic: str, index: int | None = None) -> Header:
        """:func:`header_of` with the bag's wire format (a Foxglove message's stamp, checked),
        ``SlimsegError`` naming the topic and ``index``."""
        with decoding(f"bag {self.path}: {_message(index, topic)} has no valid header"):
            if self._mcap is not None:
                return self._mcap.header(raw, topic)
            return header_of(raw, self.cdr)


def _message(index: int | None, topic: str) -> str:
    return f"{'a message' if index is None else f'message {index}'} on {topic}"


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
            with decoding(f"cannot read bag {f} ({DAMAGED})"):
                check_mcap(f)
