"""Write an MCAP of Foxglove protobuf schemas (``mcap-protobuf-support`` with
``foxglove-schemas-protobuf``, the ``slimseg[ros]`` extra): what a recording made with the
Foxglove SDK gets its masks back as. ``foxglove.RawImage`` for images, and
``foxglove.ImageAnnotations`` for boxes: each box a closed line loop of its four corners and a
text at its top-left corner.

As :class:`~slimseg.data.bags.writer.BagWriter`: built in a temporary folder beside ``path`` and
renamed into place when the writer closes cleanly; nothing is left on an exception; an
existing ``path`` is refused.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from slimseg.data.bags.header import Header, check_stamp
from slimseg.data.bags.reader import INSTALL_HINT
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import stage_name

RGBA = tuple[float, float, float, float]


def require_foxglove(path: str | Path) -> None:
    """``SlimsegError`` naming the extra when the protobuf writer or schemas are missing."""
    try:
        import foxglove_schemas_protobuf  # noqa: F401
        import mcap_protobuf  # noqa: F401
    except ImportError:
        raise SlimsegError(
            f"{path}: writing Foxglove MCAP needs mcap-protobuf-support and "
            f"foxglove-schemas-protobuf: {INSTALL_HINT}"
        ) from None


class FoxgloveWriter:
    """Messages in, a Foxglove MCAP out (use as a context manager); log time = stamp; chunks
    zstd-compressed (as the Foxglove SDK writes them) unless ``compress`` is False."""

    def __init__(self, path: str | Path, option: str = "--out", compress: bool = True) -> None:
        self.path = Path(path)
        self._option = option
        if os.path.lexists(self.path):
            raise SlimsegError(f"{option} {self.path} exists: a bag is never overwritten")
        require_foxglove(self.path)
        from mcap.writer import CompressionType
        from mcap_protobuf.writer import Writer

        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stage = self.path.with_name(stage_name(self.path.name))
        self._stage.mkdir()
        self._target = self._stage / self.path.name
        try:
            self._file = self._target.open("wb")
            kind = CompressionType.ZSTD if compress else CompressionType.NONE
            self._writer = Writer(self._file, compression=kind)
        except BaseException:
            shutil.rmtree(self._stage, ignore_errors=True)
            raise

    def __enter__(self) -> FoxgloveWriter:
        return self

    def __exit__(self, exc_type: object, *rest: object) -> None:
        try:
            if exc_type is None:
                self._writer.finish()
                self._file.close()
                os.replace(self._target, self.path)
        finally:
            self._file.close()
            shutil.rmtree(self._stage, ignore_errors=True)

    def _write(self, topic: str, header: Header, msg: object) -> None:
        check_stamp(header.ns, "foxglove", f"{self._option} {self.path}")
        msg.timestamp.FromNanoseconds(header.ns)
        self._writer.write_message(topic, msg, log_time=header.ns, publish_time=header.ns)

    def write_image(self, topic: str, header: Header, array: np.ndarray, encoding: str) -> None:
        """A ``foxglove.RawImage``: ``array [H, W]`` or ``[H, W, C]`` stored as is."""
        from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

        a = np.ascontiguousarray(array)
        h, w = a.shape[:2]
        msg = RawImage(frame_id=header.frame_id, width=w, height=h, encoding=encoding,
                       step=a.nbytes // h, data=a.tobytes())  # fmt: skip
        self._write(topic, header, msg)

    def write_calibration(
        self,
        topic: str,
        header: Header,
        size: tuple[int, int],
        k: tuple[float, float, float, float],
    ) -> None:
        """A ``foxglove.CameraCalibration``: ``size`` (w, h), ``k`` (fx, fy, cx, cy), no
        distortion (``plumb_bob`` of zeros)."""
        from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration

        fx, fy, cx, cy = k
        msg = CameraCalibration(
            frame_id=header.frame_id, width=size[0], height=size[1], distortion_model="plumb_bob",
            D=[0.0] * 5, K=[fx, 0, cx, 0, fy, cy, 0, 0, 1],
            P=[fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0],
        )  # fmt: skip
        self._write(topic, header, msg)

    def write_boxes(
        self,
        topic: str,
        header: Header,
        boxes: np.ndarray,
        labels: list[str],
        colours: list[RGBA],
    ) -> None:
        """A ``foxglove.ImageAnnotations``: per box (``boxes [M, 4]`` xyxy px) a closed loop
        of its corners in its colour (RGBA, 0-1) and its label at the top-left corner."""
        from foxglove_schemas_protobuf.Color_pb2 import Color
        from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
        from foxglove_schemas_protobuf.Point2_pb2 import Point2
        from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation

        check_stamp(header.ns, "foxglove", f"{self._option} {self.path}")
        msg = ImageAnnotations()
        for (x0, y0, x1, y1), label, rgba in zip(boxes.tolist(), labels, colours, strict=True):
            colour = Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])
            loop = msg.points.add(type=PointsAnnotation.LINE_LOOP, outline_color=colour,
                                  thickness=2.0)  # fmt: skip
            loop.points.extend([Point2(x=x, y=y) for x, y in ((x0, y0), (x1, y0), (x1, y1),
                                                               (x0, y1))])  # fmt: skip
            loop.timestamp.FromNanoseconds(header.ns)
            text = msg.texts.add(position=Point2(x=x0, y=y0), text=label, font_size=12.0,
                                 text_color=Color(r=1, g=1, b=1, a=1),
                                 background_color=colour)  # fmt: skip
            text.timestamp.FromNanoseconds(header.ns)
        self._write(topic, header, msg)
