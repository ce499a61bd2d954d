"""The fields slimseg reads from each Foxglove schema, their types, and the checks every message
passes before one of its values is used, protobuf and JSON alike.

:data:`SCHEMAS` is the one table: field name → kind, for the published schemas
(``foxglove.RawImage``, ``CompressedImage``, ``CameraCalibration``, ``PoseInFrame``,
``FrameTransform``, ``FrameTransforms``). :func:`check_descriptor` refuses a protobuf
descriptor that does not define those fields with those types (another message's descriptor
under the name, a ``data`` that is a string); :func:`read` takes a decoded message (a protobuf
object or a JSON object) and returns its values checked: integers whole and in their range,
floats finite, ``data`` bytes (in JSON a base64 string, decoded strictly), a time with its
nanoseconds in ``[0, 1e9)``, ``K`` of 9 values. A missing field takes the proto3 default, as
protobuf itself does. Anything else is a ``ValueError`` naming the field.
"""

from __future__ import annotations

import base64
import binascii
import math

from slimseg.data.bags.header import NS_PER_S

U32 = "uint32"
STR = "string"
BYTES = "bytes"
F64 = "double"
TIME = "time"
K9 = "9 doubles"
VEC3 = {"x": F64, "y": F64, "z": F64}
QUAT = {"x": F64, "y": F64, "z": F64, "w": F64}
TRANSFORM = {
    "timestamp": TIME, "parent_frame_id": STR, "child_frame_id": STR,
    "translation": VEC3, "rotation": QUAT,
}  # fmt: skip
SCHEMAS: dict[str, dict] = {
    "foxglove.RawImage": {
        "timestamp": TIME, "frame_id": STR, "width": U32, "height": U32, "encoding": STR,
        "step": U32, "data": BYTES,
    },
    "foxglove.CompressedImage": {"timestamp": TIME, "frame_id": STR, "format": STR, "data": BYTES},
    "foxglove.CameraCalibration": {
        "timestamp": TIME, "frame_id": STR, "width": U32, "height": U32,
        "distortion_model": STR, "K": K9,
    },
    "foxglove.PoseInFrame": {
        "timestamp": TIME, "frame_id": STR, "pose": {"position": VEC3, "orientation": QUAT},
    },
    "foxglove.FrameTransform": TRANSFORM,
    "foxglove.FrameTransforms": {"transforms": [TRANSFORM]},
}  # fmt: skip
MAX_SECONDS = (1 << 63) // NS_PER_S - 1  # a stamp's ns must fit a signed 64-bit integer
MAX_TRANSFORMS = 100_000

# protobuf FieldDescriptor types (google/protobuf/descriptor.proto) each kind accepts
_INTS = {3, 4, 5, 13, 15, 16, 17, 18}  # int64 uint64 int32 uint32 sfixed32 sfixed64 sint32 sint64
_PB_TYPES = {U32: _INTS | {6, 7}, STR: {9}, BYTES: {12}, F64: {1, 2}, K9: {1, 2}}
_TYPE_MESSAGE = 11


def check_descriptor(desc: object, fields: dict | None = None, where: str = "") -> None:
    """``ValueError`` unless the protobuf message descriptor ``desc`` defines ``fields`` (the
    schema's row of :data:`SCHEMAS`, by ``desc.full_name`` when None) with their kinds."""
    fields = SCHEMAS[desc.full_name] if fields is None else fields
    where = where or desc.full_name
    from google.protobuf import descriptor_pb2

    by_name = {f.name: f for f in desc.fields}
    as_proto = descriptor_pb2.DescriptorProto()  # labels read the same in every protobuf version
    desc.CopyToProto(as_proto)
    repeated_names = {f.name for f in as_proto.field if f.label == f.LABEL_REPEATED}
    for name, kind in fields.items():
        f = by_name.get(name)
        if f is None:
            raise ValueError(f"schema {where} has no field {name!r}")
        repeated = name in repeated_names
        if isinstance(kind, list):
            if not repeated or f.type != _TYPE_MESSAGE:
                raise ValueError(f"schema {where}: {name} is not a repeated message")
            check_descriptor(f.message_type, kind[0], f"{where}.{name}")
        elif isinstance(kind, dict) or kind == TIME:
            if repeated or f.type != _TYPE_MESSAGE:
                raise ValueError(f"schema {where}: {name} is not a message")
            sub = {"seconds": U32, "nanos": U32} if kind == TIME else kind
            check_descriptor(f.message_type, sub, f"{where}.{name}")
        elif f.type not in _PB_TYPES[kind] or repeated != (kind == K9):
            raise ValueError(f"schema {where}: {name} is not a {kind}")


def _get(msg: object, name: str) -> object:
    if isinstance(msg, dict):
        return msg.get(name)
    if msg is None:
        return None
    return getattr(msg, name)


def _int(v: object, where: str, lo: int, hi: int) -> int:
    if v is None:
        return 0
    if isinstance(v, float) and math.isfinite(v) and v.is_integer():
        v = int(v)
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise ValueError(f"{where} is {_show(v)}, not a whole number in [{lo}, {hi}]")
    return v


def _float(v: object, where: str) -> float:
    if v is None:
        return 0.0
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"{where} is {_show(v)}, not a finite number")
    return float(v)


def _show(v: object) -> str:
    text = repr(v) if not isinstance(v, (dict, list)) else type(v).__name__
    return text if len(text) <= 40 else text[:37] + "..."


def _time(v: object, where: str) -> int:
    """Integer ns of a protobuf ``Timestamp`` (``seconds, nanos``) or a JSON ``{sec, nsec}``."""
    if v is None:
        raise ValueError(f"{where} is missing")
    if isinstance(v, dict):
        sec, nsec = v.get("sec"), v.get("nsec")
    elif isinstance(v, (int, float, str, list, bool)):
        raise ValueError(f"{where} is {_show(v)}, not a time ({{sec, nsec}})")
    else:
        sec, nsec = v.seconds, v.nanos
    s = _int(sec, f"{where}.sec", -MAX_SECONDS, MAX_SECONDS)
    return s * NS_PER_S + _int(nsec, f"{where}.nsec", 0, NS_PER_S - 1)


def _bytes(v: object, where: str) -> bytes:
    if v is None:
        return b""
    if isinstance(v, bytes):
        return v
    if isinstance(v, str):
        try:
            return base64.b64decode(v, validate=True)
        except (binascii.Error, ValueError):
            raise ValueError(f"{where} is not base64 text") from None
    raise ValueError(f"{where} is {_show(v)}, not bytes (base64 text in JSON)")


def _str(v: object, where: str) -> str:
    if v is None:
        return ""
    if not isinstance(v, str):
        raise ValueError(f"{where} is {_show(v)}, not text")
    return v


def _list(v: object, where: str) -> list:
    if v is None:
        return []
    if isinstance(v, (str, bytes, dict, int, float)):
        raise ValueError(f"{where} is {_show(v)}, not a list")
    return list(v)


def read(msg: object, fields: dict, where: str) -> dict:
    """The values of ``fields`` in ``msg`` (a protobuf message or a JSON object), checked (see
    the module docstring); nested messages as dicts. ``ValueError`` naming the field."""
    if isinstance(msg, (str, bytes, int, float, list)):
        raise ValueError(f"{where} is {_show(msg)}, not an object")
    out: dict = {}
    for name, kind in fields.items():
        v, at = _get(msg, name), f"{where}.{name}"
        if isinstance(kind, list):
            items = _list(v, at)
            if len(items) > MAX_TRANSFORMS:
                raise ValueError(f"{at} holds {len(items)} items, more than {MAX_TRANSFORMS}")
            out[name] = [read(x, kind[0], f"{at}[{i}]") for i, x in enumerate(items)]
        elif isinstance(kind, dict):
            out[name] = read(v, kind, at)
        elif kind == TIME:
            out[name] = _time(v, at)
        elif kind == U32:
            out[name] = _int(v, at, 0, (1 << 32) - 1)
        elif kind == F64:
            out[name] = _float(v, at)
        elif kind == STR:
            out[name] = _str(v, at)
        elif kind == BYTES:
            out[name] = _bytes(v, at)
        else:  # K9: 9 finite values, or none given (an uncalibrated camera, refused later)
            k = [_float(x, f"{at}[{i}]") for i, x in enumerate(_list(v, at)[:10])]
            if k and len(k) != 9:
                raise ValueError(f"{at} holds {len(_list(v, at))} values, expected 9 (3x3)")
            out[name] = k or [0.0] * 9
    return out
