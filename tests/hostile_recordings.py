"""Small Foxglove and ROS 2 recordings with one thing wrong, written by the independent libraries
(the ``mcap`` package's ``Writer``, foxglove-schemas-protobuf's message classes, rosbags' rosbag2
writer), for ``tests/data/bags/test_bags_hostile.py``.

Each recording holds :data:`N` frames of :data:`W` x :data:`H`: colour ``rgb8`` (a pattern that
differs per frame), depth ``16UC1`` at 2 m, and a ``CameraCalibration`` per frame. ``edit``
hooks change one message's fields (or replace its bytes) before it is written.
"""

from __future__ import annotations

import base64
import json
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np

N, W, H = 4, 16, 12
T0, DT = 100_000_000_000, 33_333_333
COLOUR, DEPTH, INFO = "/cam/color/image_raw", "/cam/depth/image_raw", "/cam/color/camera_info"
K = [105.0, 0.0, 7.5, 0.0, 105.0, 5.5, 0.0, 0.0, 1.0]
Edit = Callable[[int, object], object] | None


def colour(i: int) -> np.ndarray:
    y, x = np.mgrid[0:H, 0:W]
    return np.stack([(x * 9 + i * 7) % 256, (y * 13) % 256, (x + y + 40 * i) % 256], -1).astype(
        np.uint8
    )


def depth() -> np.ndarray:
    return np.full((H, W), 2000, np.uint16)


def stamps(first: int = T0) -> list[int]:
    return [first + i * DT for i in range(N)]


def _write(path: Path, chans: list[tuple], msgs: list[tuple], compression: str = "none",
           chunk_size: int = 1 << 20) -> Path:  # fmt: skip
    """``chans``: ``(topic, schema name, schema encoding, schema bytes, message encoding)``;
    ``msgs``: ``(channel index, stamp ns, bytes)``, logged 30 ms after the stamp (and never
    before 1970)."""
    from mcap.writer import CompressionType, Writer

    kind = {"none": CompressionType.NONE, "zstd": CompressionType.ZSTD}[compression]
    with path.open("wb") as f:
        w = Writer(f, compression=kind, chunk_size=chunk_size)
        w.start(profile="", library="slimseg tests")
        sids: dict = {}
        cids = []
        for topic, name, senc, sdata, menc in chans:
            if (name, senc, sdata) not in sids:
                sids[(name, senc, sdata)] = w.register_schema(name, senc, sdata)
            cids.append(w.register_channel(topic, menc, sids[(name, senc, sdata)]))
        for ci, ns, data in msgs:
            log = max(ns, 0) + 30_000_000
            w.add_message(cids[ci], log_time=log, data=data, publish_time=log)
        w.finish()
    return path


def _fds(cls: type) -> bytes:
    from mcap_protobuf.schema import build_file_descriptor_set

    return build_file_descriptor_set(cls).SerializeToString()


def protobuf_recording(
    path: Path, edit: Edit = None, schema: bytes | None = None, k: list[float] = K,
    times: list[int] | None = None, compression: str = "none", chunk_size: int = 1 << 20,
) -> Path:  # fmt: skip
    """Foxglove protobuf: ``edit(i, RawImage)`` may change colour frame ``i`` (or return bytes);
    ``schema``: the colour channel's ``FileDescriptorSet`` bytes in place of RawImage's."""
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    def image(ns: int, a: np.ndarray, enc: str) -> RawImage:
        m = RawImage(frame_id="cam", width=W, height=H, encoding=enc, step=a.nbytes // H,
                     data=a.tobytes())  # fmt: skip
        m.timestamp.FromNanoseconds(ns)
        return m

    chans = [(COLOUR, "foxglove.RawImage", "protobuf", schema or _fds(RawImage), "protobuf"),
             (DEPTH, "foxglove.RawImage", "protobuf", _fds(RawImage), "protobuf"),
             (INFO, "foxglove.CameraCalibration", "protobuf", _fds(CameraCalibration),
              "protobuf")]  # fmt: skip
    msgs = []
    for i, ns in enumerate(times or stamps()):
        c = image(ns, colour(i), "rgb8")
        c = edit(i, c) if edit else c
        info = CameraCalibration(frame_id="cam", width=W, height=H, distortion_model="plumb_bob",
                                 K=k)  # fmt: skip
        info.timestamp.FromNanoseconds(ns)
        msgs += [(0, ns, c if isinstance(c, bytes) else c.SerializeToString()),
                 (1, ns, image(ns, depth(), "16UC1").SerializeToString()),
                 (2, ns, info.SerializeToString())]  # fmt: skip
    return _write(path, chans, msgs, compression, chunk_size)


def json_recording(path: Path, edit: Edit = None, info_edit: Edit = None) -> Path:
    """Foxglove JSON: ``edit(i, dict)`` may change colour frame ``i`` (or return bytes),
    ``info_edit(i, dict)`` its calibration."""

    def image(ns: int, a: np.ndarray, enc: str) -> dict:
        return {"timestamp": {"sec": ns // 10**9, "nsec": ns % 10**9}, "frame_id": "cam",
                "width": W, "height": H, "encoding": enc, "step": a.nbytes // H,
                "data": base64.b64encode(a.tobytes()).decode()}  # fmt: skip

    def dumps(v: object) -> bytes:
        return v if isinstance(v, bytes) else json.dumps(v).encode()

    chans = [(COLOUR, "foxglove.RawImage", "jsonschema", b"{}", "json"),
             (DEPTH, "foxglove.RawImage", "jsonschema", b"{}", "json"),
             (INFO, "foxglove.CameraCalibration", "jsonschema", b"{}", "json")]  # fmt: skip
    msgs = []
    for i, ns in enumerate(stamps()):
        c = image(ns, colour(i), "rgb8")
        info = {"timestamp": {"sec": ns // 10**9, "nsec": ns % 10**9}, "frame_id": "cam",
                "width": W, "height": H, "distortion_model": "plumb_bob", "K": K}  # fmt: skip
        msgs += [(0, ns, dumps(edit(i, c) if edit else c)),
                 (1, ns, dumps(image(ns, depth(), "16UC1"))),
                 (2, ns, dumps(info_edit(i, info) if info_edit else info))]  # fmt: skip
    return _write(path, chans, msgs)


def ros2_recording(path: Path, times: list[int]) -> Path:
    """A rosbag2 folder (MCAP storage, rosbags' writer) whose header stamps are ``times``
    (before 1970 allowed) and whose log times are after 1970."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    image, header, time = (ts.types[n] for n in ("sensor_msgs/msg/Image", "std_msgs/msg/Header",
                                                 "builtin_interfaces/msg/Time"))  # fmt: skip
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        cc = w.add_connection(COLOUR, image.__msgtype__, typestore=ts)
        cd = w.add_connection(DEPTH, image.__msgtype__, typestore=ts)
        for i, ns in enumerate(times):
            sec, nsec = divmod(ns, 10**9)
            hdr = header(stamp=time(sec=sec, nanosec=nsec), frame_id="cam")
            for conn, a, enc in ((cc, colour(i), "rgb8"), (cd, depth(), "16UC1")):
                msg = image(header=hdr, height=H, width=W, encoding=enc, is_bigendian=0,
                            step=a.nbytes // H, data=a.reshape(-1).view(np.uint8))  # fmt: skip
                w.write(conn, T0 + i * DT, ts.serialize_cdr(msg, image.__msgtype__))
    return path


def chunks(data: bytes) -> list[tuple[int, int]]:
    """``(offset, length)`` of each Chunk record of an MCAP file's bytes."""
    out, pos = [], 8
    while pos + 9 <= len(data):
        op, n = struct.unpack_from("<BQ", data, pos)
        if op == 0x02:
            break
        if op == 0x06:
            out.append((pos, n))
        pos += 9 + n
    return out
