"""Every byte a recording holds is checked (issue #62): the hostile recordings of probe 7, each
read by ``slimseg data bag2tum``, end in one line naming the recording (exit 2, nothing
written) or are read exactly. Damaged chunks and unknown compressions, Foxglove JSON values of
the wrong type or size, protobuf schemas that do not build or define another message, a lost
chunk, stamps before 1970 (read in order to the nanosecond; refused on write)."""

from __future__ import annotations

import sqlite3
import struct
from pathlib import Path

import cv2
import hostile_recordings as hr
import numpy as np
import pytest

from slimseg.cli.main import main
from slimseg.data.bags.header import Header, stamp_text
from slimseg.data.bags.reader import BagFile

pytest.importorskip("rosbags")
pytest.importorskip("mcap_protobuf")


def _bag2tum(bag: Path, out: Path) -> list[str]:
    return ["data", "bag2tum", "--bag", str(bag), "--out", str(out), "--quiet"]


def _refused(capsys, bag: Path, out: Path, *fragments: str) -> str:
    assert main(_bag2tum(bag, out)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(bag) in err, err
    for f in fragments:
        assert f in err, (f, err)
    assert not out.exists()
    return err


def _garble_chunk(src: Path, dst: Path, which: str) -> Path:
    data = bytearray(src.read_bytes())
    chunks = hr.chunks(bytes(data))
    assert len(chunks) > 3
    pos, _ = chunks[len(chunks) // 2]
    body = pos + 9
    clen = struct.unpack_from("<I", data, body + 28)[0]
    if which == "bytes":  # 60 bytes garbled inside the compressed records
        at = body + 32 + clen + 8 + 20
        data[at : at + 60] = bytes((b + 77) % 256 for b in data[at : at + 60])
    else:  # the compression renamed to one MCAP does not define
        data[body + 32 : body + 32 + clen] = b"z" * clen
    dst.write_bytes(bytes(data))
    return dst


@pytest.mark.parametrize("which", ["bytes", "compression"])
def test_a_damaged_or_unknown_chunk_is_refused_not_read(tmp_path: Path, capsys, which: str):
    ok = hr.protobuf_recording(tmp_path / "ok.mcap", compression="zstd", chunk_size=600)
    bad = _garble_chunk(ok, tmp_path / "bad.mcap", which)
    want = "compressed with 'zzzz'" if which == "compression" else "does not decompress"
    _refused(capsys, bad, tmp_path / "out", want)
    assert main(_bag2tum(ok, tmp_path / "good")) == 0  # the undamaged file reads


def test_a_lost_chunk_is_refused_by_the_summarys_counts(tmp_path: Path, capsys) -> None:
    """The statistics list one colour message more than the chunks hold (a chunk lost from
    the index, as a writer that leaves the summary CRC at 0 would not notice)."""
    from mcap.reader import make_reader

    ok = hr.protobuf_recording(tmp_path / "ok.mcap")
    data = bytearray(ok.read_bytes())
    with ok.open("rb") as f:
        stats = make_reader(f).get_summary().statistics
    counts = stats.channel_message_counts
    colour_id = min(counts)
    # channel_message_counts is a map of u16 id -> u64 count at the Statistics record's end
    entry = struct.pack("<HQ", colour_id, counts[colour_id])
    at = bytes(data).rindex(entry)
    data[at + 2 : at + 10] = struct.pack("<Q", counts[colour_id] + 1)
    data[len(data) - 8 - 4 : len(data) - 8] = b"\0" * 4  # summary CRC: "not computed"
    bad = tmp_path / "lost.mcap"
    bad.write_bytes(bytes(data))
    _refused(capsys, bad, tmp_path / "out", f"4 messages on {hr.COLOUR} read where its index "
             "lists 5")  # fmt: skip


def test_a_lost_sqlite_row_is_refused(tmp_path: Path, capsys) -> None:
    src = hr.protobuf_recording(tmp_path / "ok.mcap")
    assert main(_bag2tum(src, tmp_path / "tum")) == 0
    assert main(["data", "tum2bag", "--sequence", str(tmp_path / "tum"), "--out",
                 str(tmp_path / "r2"), "--bag-storage", "sqlite3"]) == 0  # fmt: skip
    db = next((tmp_path / "r2").glob("*.db3"))
    with sqlite3.connect(db) as c:
        c.execute("DELETE FROM messages WHERE id = (SELECT MAX(id) FROM messages)")
    _refused(capsys, tmp_path / "r2", tmp_path / "out", "read where its index lists")


def _set(field: str, value: object, frame: int | None = 0):
    def edit(i: int, msg: dict) -> object:
        return {**msg, field: value} if frame is None or i == frame else msg

    return edit


DEEP = b'{"timestamp": {"sec": 1, "nsec": 0}, "frame_id": ' + b"[" * 200_000 + b"]" * 200_000 + b"}"
JSON_CASES = {
    "data_int_bomb": (_set("data", 6_000_000_000), None, "data is 6000000000, not bytes"),
    "data_not_base64": (_set("data", "!!not base64!!", None), None, "data is not base64"),
    "sec_infinity": (_set("timestamp", {"sec": float("inf"), "nsec": 0}), None, "timestamp.sec"),
    "sec_list": (_set("timestamp", {"sec": [1], "nsec": 0}), None, "timestamp.sec is list"),
    "timestamp_number": (_set("timestamp", 5), None, "timestamp is 5, not a time"),
    "sec_huge": (_set("timestamp", {"sec": 10**20, "nsec": 0}), None, "timestamp.sec"),
    "width_negative": (_set("width", -16, None), None, "width is -16, not a whole number"),
    "height_text": (_set("height", "12", None), None, "height is '12', not a whole number"),
    "deep": (lambda i, m: DEEP if i == 0 else m, None, "RecursionError"),
    "list_message": (lambda i, m: b"[1, 2, 3]" if i == 0 else m, None, "not an object"),
    "not_utf8": (lambda i, m: b"\xff\xfe{" if i == 0 else m, None, "message 0 on"),
    "k_short": (None, lambda i, m: {**m, "K": [105, 0, 7.5]}, "K holds 3 values, expected 9"),
    "k_text": (None, lambda i, m: {**m, "K": "abcdefghi"}, "K is 'abcdefghi', not a list"),
}


@pytest.mark.parametrize("name", list(JSON_CASES))
def test_foxglove_json_values_are_checked_against_the_schema(tmp_path: Path, capsys, name: str):
    edit, info_edit, fragment = JSON_CASES[name]
    bad = hr.json_recording(tmp_path / f"{name}.mcap", edit, info_edit)
    _refused(capsys, bad, tmp_path / "out", fragment)


def _schemas() -> dict[str, bytes]:
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
    from google.protobuf.descriptor_pb2 import FileDescriptorSet

    good = FileDescriptorSet.FromString(hr._fds(RawImage))
    missing = FileDescriptorSet()
    missing.file.extend(f for f in good.file if "timestamp" not in f.name)
    selfdep = FileDescriptorSet.FromString(hr._fds(RawImage))
    for f in selfdep.file:
        f.dependency.append(f.name)
    return {
        "garbage": bytes(range(256)) * 2,
        "another_message": hr._fds(CompressedImage),
        "missing_dependency": missing.SerializeToString(),
        "self_dependency": selfdep.SerializeToString(),
    }


@pytest.mark.parametrize("name", ["garbage", "another_message", "missing_dependency",
                                  "self_dependency"])  # fmt: skip
def test_protobuf_schemas_are_built_inside_the_boundary(tmp_path: Path, capsys, name: str):
    bad = hr.protobuf_recording(tmp_path / f"{name}.mcap", schema=_schemas()[name])
    _refused(capsys, bad, tmp_path / "out", f"message 0 on {hr.COLOUR}")


def test_protobuf_calibration_of_three_values_is_refused(tmp_path: Path, capsys) -> None:
    bad = hr.protobuf_recording(tmp_path / "k3.mcap", k=[105.0, 0.0, 7.5])
    _refused(capsys, bad, tmp_path / "out", "K holds 3 values, expected 9")


def test_protobuf_data_of_the_wrong_size_is_refused(tmp_path: Path, capsys) -> None:
    def short(i: int, m: object) -> object:
        m.data = m.data[:-7] if i == 2 else m.data
        return m

    bad = hr.protobuf_recording(tmp_path / "short.mcap", edit=short)
    _refused(capsys, bad, tmp_path / "out", "colour topic")


def _read_tum(out: Path) -> list[tuple[str, np.ndarray]]:
    rows = [ln.split() for ln in (out / "rgb.txt").read_text().splitlines() if ln[:1] != "#"]
    return [(t, cv2.cvtColor(cv2.imread(str(out / f)), cv2.COLOR_BGR2RGB)) for t, f in rows]


NEGATIVE = hr.stamps(-5_000_000_000)


@pytest.mark.parametrize("kind", ["foxglove", "ros2"])
def test_stamps_before_1970_are_read_in_order_to_the_nanosecond(tmp_path: Path, kind: str):
    src = (
        hr.protobuf_recording(tmp_path / "neg.mcap", times=NEGATIVE)
        if kind == "foxglove"
        else hr.ros2_recording(tmp_path / "neg", NEGATIVE)
    )
    assert main(_bag2tum(src, tmp_path / "tum")) == 0
    rows = _read_tum(tmp_path / "tum")
    assert [t for t, _ in rows] == ["-5.000000", "-4.966667", "-4.933333", "-4.900000"]
    for i, (_, rgb) in enumerate(rows):
        assert np.array_equal(rgb, hr.colour(i)), i
    with BagFile(src) as bag:
        got = [bag.header(raw, t).ns for t, _, raw in bag.messages([hr.COLOUR])]
    assert got == NEGATIVE


def test_signed_stamp_text_is_exact() -> None:
    assert stamp_text(-4_966_666_667) == "-4.966666667"
    assert Header(-4_966_666_667, "").seconds == -4.966666667
    assert Header(-1, "").seconds < Header(0, "").seconds < Header(1, "").seconds


@pytest.mark.parametrize("out", ["x.mcap", "x.bag", "x2"])
def test_writing_a_stamp_before_1970_is_refused_in_one_line(tmp_path: Path, capsys, out: str):
    src = hr.protobuf_recording(tmp_path / "neg.mcap", times=NEGATIVE)
    assert main(_bag2tum(src, tmp_path / "tum")) == 0
    target = tmp_path / out
    args = ["data", "tum2bag", "--sequence", str(tmp_path / "tum"), "--out", str(target)]
    assert main(args + (["--bag-storage", "sqlite3"] if out == "x2" else [])) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(target) in err and "-5.000000000 s cannot be" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["neg.mcap", "tum"]
