"""A bare ``.mcap`` file read by the schema encoding each of its channels holds, not only by the
``ros2`` profile rosbags reads: ``ros1msg`` schemas with ``ros1`` messages (what ``mcap convert``
makes of a ROS 1 bag), ``ros2msg`` with ``cdr``, and the Foxglove schemas (``protobuf``, an
embedded ``FileDescriptorSet``; ``jsonschema`` with ``json`` messages) that robots logging
without ROS record (:mod:`slimseg.data.bags.foxglove_messages`).

:func:`mcap_channels` lists a file's channels from its summary (or, lacking one, by scanning
its records); :class:`McapFile` yields raw messages in log-time order and decodes them. ROS
messages decode with rosbags' type stores (a type the store lacks is built from the schema's
own definition); Foxglove ones to the shapes :mod:`slimseg.data.bags.image_messages` and the
pose reader take. A file none of whose channels slimseg can decode is refused in one line
naming what it holds and what is read (:func:`refuse_unreadable`).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from slimseg.data.bags.foxglove_fields import check_descriptor
from slimseg.data.bags.foxglove_messages import FOXGLOVE_ROLES, foxglove_header, foxglove_view
from slimseg.data.bags.header import (
    CAMERA_INFO,
    COMPRESSED,
    DAMAGED,
    IMAGE,
    ODOMETRY,
    POSE,
    TF,
    Header,
    header_of,
)
from slimseg.errors import SlimsegError

ROS_ROLES = (IMAGE, COMPRESSED, CAMERA_INFO, POSE, ODOMETRY, TF)

# (schema encoding, message encoding) pairs decoded, and the profile each one belongs to
ENCODINGS = {
    ("ros1msg", "ros1"): "ros1",
    ("ros2msg", "cdr"): "ros2",
    ("protobuf", "protobuf"): "foxglove protobuf",
    ("jsonschema", "json"): "foxglove JSON",
}
SUPPORTED = (
    "ros1msg/ros1 and ros2msg/cdr sensor_msgs, geometry_msgs, nav_msgs and tf2_msgs messages, "
    "and Foxglove protobuf or JSON schemas ("
    + ", ".join(sorted({n.removeprefix("foxglove.") for n in FOXGLOVE_ROLES}))
    + ")"
)


@dataclass(frozen=True)
class McapChannel:
    """One channel: ``topic``, its schema's ``name`` and ``encoding``, the message encoding,
    and ``role`` (the ROS 2 type name slimseg treats it as; None: nothing slimseg uses)."""

    id: int
    topic: str
    schema: str
    schema_encoding: str
    message_encoding: str
    schema_data: bytes
    role: str | None
    count: int | None = None  # messages the summary's statistics list (None: no statistics)

    @property
    def kind(self) -> str:
        """How a listing shows it: ``foxglove.RawImage (protobuf)``."""
        return f"{self.schema or 'no schema'} ({self.schema_encoding or self.message_encoding})"


def ros_type_name(schema: str) -> str:
    """A ROS type in rosbags' spelling: ``sensor_msgs/Image`` (ROS 1) →
    ``sensor_msgs/msg/Image``; a ROS 2 name is kept."""
    parts = schema.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else schema


def _role(schema: str, schema_enc: str, msg_enc: str) -> str | None:
    profile = ENCODINGS.get((schema_enc, msg_enc))
    if profile is None:
        return None
    if profile.startswith("foxglove"):
        return FOXGLOVE_ROLES.get(schema)
    name = ros_type_name(schema)
    return name if name in ROS_ROLES else None


def mcap_channels(path: Path) -> tuple[str, list[McapChannel]] | None:
    """``(profile, channels)`` of the MCAP file ``path``, from its summary or, lacking one (a
    recording cut short), by scanning its records. None when its header does not parse or it
    is of the ``ros2`` profile and does not parse further (rosbags' reader then names the
    damage, as before); any other profile that does not parse is a damaged recording."""
    from mcap.reader import make_reader
    from mcap.records import Channel, Schema
    from mcap.stream_reader import StreamReader

    profile = None
    try:
        with path.open("rb") as f:
            reader = make_reader(f)
            profile = reader.get_header().profile
            try:
                summary = reader.get_summary()
            except Exception:  # no footer (a recording cut short): scan the records
                summary = None
            counts = None
            if summary is not None:
                schemas, channels = summary.schemas, summary.channels
                if summary.statistics is not None:
                    counts = summary.statistics.channel_message_counts
            else:  # no summary section: the schemas and channels are among the records
                f.seek(0)
                schemas, channels = {}, {}
                for rec in StreamReader(f, skip_magic=False).records:
                    if isinstance(rec, Schema):
                        schemas[rec.id] = rec
                    elif isinstance(rec, Channel):
                        channels[rec.id] = rec
    except Exception as e:  # the mcap parser's errors on a damaged file, all of them
        if profile is None or profile == "ros2":
            return None
        reason = " ".join(str(e).split())[:300] or type(e).__name__
        raise SlimsegError(f"cannot read bag {path}: {reason} ({DAMAGED})") from None
    out = []
    for c in channels.values():
        s = schemas.get(c.schema_id)
        name, enc, data = (s.name, s.encoding, s.data) if s is not None else ("", "", b"")
        out.append(McapChannel(c.id, c.topic, name, enc, c.message_encoding, data,
                               _role(name, enc, c.message_encoding),
                               None if counts is None else counts.get(c.id, 0)))  # fmt: skip
    return profile, sorted(out, key=lambda c: c.id)


def rosbags_reads(profile: str, channels: list[McapChannel]) -> bool:
    """Whether rosbags' own MCAP reader takes the file: the ``ros2`` profile, ROS 2 schemas."""
    return profile == "ros2" and all(c.schema_encoding in ("ros2msg", "ros2idl") for c in channels)


def refuse_unreadable(path: Path, profile: str, channels: list[McapChannel]) -> None:
    """``SlimsegError`` (one line) when no channel of ``path`` is one slimseg decodes and uses."""
    if any(c.role is not None for c in channels):
        return
    held = sorted({c.kind for c in channels}) or ["no channels"]
    shown = ", ".join(held[:6]) + (f" and {len(held) - 6} more" if len(held) > 6 else "")
    raise SlimsegError(
        f"recording {path} (MCAP profile {profile or 'none'!r}) holds no channel slimseg can "
        f"decode: {shown}; slimseg reads {SUPPORTED}"
    )


class McapFile:
    """The channels of an MCAP file as :class:`~slimseg.data.bags.reader.BagFile` needs them:
    raw messages in log-time order, headers and decoded messages by topic."""

    def __init__(self, path: Path, channels: list[McapChannel]) -> None:
        from mcap.reader import make_reader

        self.path = path
        self.channels = channels
        self._by_topic = {}
        for c in channels:
            self._by_topic.setdefault(c.topic, c)
        self._file = path.open("rb")
        self._reader = make_reader(self._file, validate_crcs=True)
        self._stores: dict[str, object] = {}
        self._protobuf: dict[str, type] = {}

    def close(self) -> None:
        self._file.close()

    def messages(self, topics: list[str], start_ns: int | None) -> Iterator[tuple[str, int, bytes]]:
        """``(topic, log time ns, raw bytes)`` of ``topics`` in log-time order."""
        it = self._reader.iter_messages(topics=topics, starting_at=start_ns, log_time_order=True)
        for _, channel, message in it:
            yield channel.topic, message.log_time, message.data

    def _channel(self, topic: str) -> McapChannel:
        return self._by_topic[topic]

    def profile(self, topic: str) -> str:
        """``ros1``, ``ros2``, ``foxglove protobuf`` or ``foxglove JSON`` (see :data:`ENCODINGS`)
        for a decodable channel, else its schema encoding."""
        c = self._channel(topic)
        return ENCODINGS.get((c.schema_encoding, c.message_encoding), c.schema_encoding)

    def header(self, raw: bytes, topic: str) -> Header:
        """The message's stamp and frame: from the bytes for ROS messages, from the decoded
        message for Foxglove ones. ``ValueError`` when there is none."""
        c = self._channel(topic)
        if c.message_encoding in ("ros1", "cdr"):
            return header_of(raw, c.message_encoding == "cdr")
        return foxglove_header(self._parse(raw, c))

    def decode(self, raw: bytes, topic: str) -> object:
        """The message: a rosbags object for ROS channels, a view for Foxglove ones."""
        c = self._channel(topic)
        if c.message_encoding in ("ros1", "cdr"):
            store = self._store(c)
            name = ros_type_name(c.schema)
            if c.message_encoding == "cdr":
                return store.deserialize_cdr(raw, name)
            return store.deserialize_ros1(raw, name)
        return foxglove_view(c.schema, self._parse(raw, c))

    def _store(self, c: McapChannel) -> object:
        """The rosbags type store of ``c``'s ROS generation, with its type registered from the
        schema text when the store lacks it."""
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        ros1 = c.message_encoding == "ros1"
        key = "ros1" if ros1 else "ros2"
        if key not in self._stores:
            self._stores[key] = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        store = self._stores[key]
        name = ros_type_name(c.schema)
        if name not in store.types:
            store.register(get_types_from_msg(c.schema_data.decode(), name))
        return store

    def _parse(self, raw: bytes, c: McapChannel) -> object:
        """A Foxglove message: a protobuf message object, or the JSON object."""
        if c.message_encoding == "json":
            return json.loads(raw)
        if c.schema not in self._protobuf:
            self._protobuf[c.schema] = _protobuf_class(c)
        msg = self._protobuf[c.schema]()
        msg.ParseFromString(raw)  # protobuf's DecodeError: the caller's boundary names it
        return msg


def _protobuf_class(c: McapChannel) -> type:
    """The message class of ``c``'s schema, built from its embedded ``FileDescriptorSet`` and
    checked to define the fields slimseg reads with their types (``ValueError`` otherwise;
    protobuf's own errors on a set that does not build are left to the caller's boundary)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    files = list(descriptor_pb2.FileDescriptorSet.FromString(c.schema_data).file)
    pool = descriptor_pool.DescriptorPool()
    added: set[str] = set()
    while files:  # dependencies first, whatever order the writer put them in
        ready = [f for f in files if set(f.dependency) <= added] or files[:1]
        for f in ready:
            pool.Add(f)
            added.add(f.name)
            files.remove(f)
    try:
        desc = pool.FindMessageTypeByName(c.schema)
    except KeyError:
        raise ValueError(f"its FileDescriptorSet does not define {c.schema}") from None
    check_descriptor(desc)
    return message_factory.GetMessageClass(desc)
