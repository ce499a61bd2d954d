"""MCAP checksums: written into the recordings slimseg makes, checked in every one it reads.

An MCAP file may carry CRC-32s of each chunk's records and of its whole data section (the
``DataEnd`` record); a zero means "not computed". ``rosbags`` checks a chunk's CRC when it
decompresses it but never the data section's, and its writer leaves both at zero, so 2 KB of
random bytes in the middle of a recording slimseg wrote were read as pixels. :func:`seal`
fills both in after a recording is written (before it is renamed into place);
:func:`check_data_crc` compares the data section's CRC, where one is recorded, before a
recording is read, and names the file when they differ.

Layout used (MCAP spec): magic ``\\x89MCAP0\\r\\n``; records ``opcode u8, length u64, body``;
a Chunk (0x06) body starts ``start u64, end u64, uncompressed_size u64, uncompressed_crc u32,
compression (u32 length + text), records (u64 length + bytes)``; DataEnd (0x0F) holds
``data_section_crc u32``; the file ends with a Footer (0x02: ``summary_start u64,
summary_offset_start u64, summary_crc u32``) and the magic again.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path
from typing import BinaryIO

from slimseg.data.bags.header import DAMAGED
from slimseg.errors import SlimsegError

MAGIC = b"\x89MCAP0\r\n"
_CHUNK, _DATA_END, _FOOTER = 0x06, 0x0F, 0x02
_FOOTER_LEN = 1 + 8 + 20  # opcode, length, body
_DATA_END_LEN = 1 + 8 + 4
_BLOCK = 1 << 20
MAX_CHUNK = 1 << 30  # bytes a chunk may declare uncompressed: more is refused, not allocated


def _crc(f: BinaryIO, start: int, size: int) -> int:
    """CRC-32 of ``size`` bytes of ``f`` from ``start``, read in blocks."""
    f.seek(start)
    crc, left = 0, size
    while left > 0:
        block = f.read(min(_BLOCK, left))
        if not block:
            break
        crc = zlib.crc32(block, crc)
        left -= len(block)
    return crc


def _data_end(f: BinaryIO, size: int) -> int | None:
    """Offset of the ``DataEnd`` record, found from the footer; ``None`` when the file does not
    end the way a finished MCAP does (a truncated file: left to the reader to refuse)."""
    if size < len(MAGIC) * 2 + _FOOTER_LEN + _DATA_END_LEN:
        return None
    f.seek(size - len(MAGIC) - _FOOTER_LEN)
    footer = f.read(_FOOTER_LEN + len(MAGIC))
    if footer[-len(MAGIC) :] != MAGIC or footer[0] != _FOOTER:
        return None
    summary_start = struct.unpack_from("<Q", footer, 9)[0]
    at = summary_start if summary_start else size - len(MAGIC) - _FOOTER_LEN
    at -= _DATA_END_LEN
    if not len(MAGIC) <= at <= size - len(MAGIC) - _FOOTER_LEN - _DATA_END_LEN:
        return None
    f.seek(at)
    head = f.read(9)
    if len(head) < 9 or head[0] != _DATA_END or struct.unpack_from("<Q", head, 1)[0] != 4:
        return None
    return at


def check_mcap(path: str | Path) -> None:
    """Every checksum a finished MCAP file carries, before any reader sees it: its data
    section's CRC (where recorded), each chunk's (where recorded; the chunk decompressed with
    a compression the spec names, to the size it declares) and its summary section's. A
    chunk that cannot be decompressed is refused, never skipped. ``SlimsegError`` naming
    ``path`` and what does not match; a file that is not a finished MCAP passes unchecked
    (the reader refuses it as truncated)."""
    path = Path(path)
    with path.open("rb") as f:
        size = os.fstat(f.fileno()).st_size
        at = _data_end(f, size)
        if at is None:
            return
        f.seek(at + 9)
        recorded = struct.unpack("<I", f.read(4))[0]
        if recorded and _crc(f, 0, at) != recorded:
            _refuse(path, "its data-section checksum (CRC-32) does not match its bytes")
        pos = _first_record(f, path)
        while pos < at:
            f.seek(pos)
            head = f.read(9)
            if len(head) < 9:
                _refuse(path, f"the record at byte {pos} is cut off")
            op, length = struct.unpack("<BQ", head)
            if pos + 9 + length > at:
                _refuse(path, f"the record at byte {pos} runs past its data section")
            if op == _CHUNK:
                _check_chunk(f, path, pos + 9, length)
            pos += 9 + length
        _check_summary(f, path, size)


def _refuse(path: Path, why: str) -> None:
    raise SlimsegError(f"cannot read bag {path}: {why} ({DAMAGED})")


def _first_record(f: BinaryIO, path: Path) -> int:
    """Offset of the record after the magic and the Header record."""
    f.seek(0)
    head = f.read(len(MAGIC) + 9)
    if len(head) < len(MAGIC) + 9 or head[: len(MAGIC)] != MAGIC or head[len(MAGIC)] != 0x01:
        _refuse(path, "it does not start with an MCAP magic and header")
    return len(MAGIC) + 9 + struct.unpack_from("<Q", head, len(MAGIC) + 1)[0]


def _check_chunk(f: BinaryIO, path: Path, body: int, length: int) -> None:
    f.seek(body + 16)
    fixed = f.read(16)
    if len(fixed) < 16:
        _refuse(path, f"the chunk at byte {body - 9} is cut off")
    usize, crc, clen = struct.unpack("<QII", fixed)
    if clen > 64 or 16 + 16 + clen + 8 > length:
        _refuse(path, f"the chunk at byte {body - 9} has a malformed compression field")
    compression = f.read(clen).decode("ascii", "replace")
    clen_records = struct.unpack("<Q", f.read(8))[0]
    if 32 + clen + 8 + clen_records != length:
        _refuse(path, f"the chunk at byte {body - 9} does not hold the bytes it declares")
    if compression not in _DECOMPRESS:
        _refuse(path, f"the chunk at byte {body - 9} is compressed with {compression!r}, "
                "which MCAP does not define (zstd, lz4 or none)")  # fmt: skip
    if usize > MAX_CHUNK:
        _refuse(path, f"the chunk at byte {body - 9} declares {usize} bytes uncompressed, "
                f"more than {MAX_CHUNK}")  # fmt: skip
    data = f.read(clen_records)
    try:
        raw = _DECOMPRESS[compression](data, usize)
    except Exception:  # zstd's / lz4's errors on damaged bytes, all of them
        _refuse(path, f"the {compression} chunk at byte {body - 9} does not decompress")
    if len(raw) != usize:
        _refuse(path, f"the chunk at byte {body - 9} decompresses to {len(raw)} bytes, "
                f"not the {usize} it declares")  # fmt: skip
    if crc and zlib.crc32(raw) != crc:
        _refuse(path, f"the chunk at byte {body - 9} does not match its checksum (CRC-32)")


def _check_summary(f: BinaryIO, path: Path, size: int) -> None:
    f.seek(size - len(MAGIC) - _FOOTER_LEN)
    footer = f.read(_FOOTER_LEN)
    summary_start, _, crc = struct.unpack_from("<QQI", footer, 9)
    if not summary_start or not crc:
        return
    # the CRC covers the summary section through the footer's summary_offset_start field
    end = size - len(MAGIC) - 4
    if summary_start > end or _crc(f, summary_start, end - summary_start) != crc:
        _refuse(path, "its summary section does not match its checksum (CRC-32)")


def _zstd(data: bytes, size: int) -> bytes:
    import zstandard

    return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)


def _lz4(data: bytes, size: int) -> bytes:
    import lz4.frame

    return lz4.frame.decompress(data)


_DECOMPRESS = {"": lambda data, size: data, "zstd": _zstd, "lz4": _lz4}


def seal(path: str | Path) -> None:
    """Write the CRC-32 of every uncompressed chunk whose CRC is zero, then the data
    section's, into the MCAP file ``path`` (one that slimseg has just written, in place)."""
    path = Path(path)
    with path.open("r+b") as f:
        size = os.fstat(f.fileno()).st_size
        at = _data_end(f, size)
        if at is None:
            raise SlimsegError(f"{path}: not a finished MCAP file")
        pos = len(MAGIC)
        while pos < at:
            f.seek(pos)
            op, length = struct.unpack("<BQ", f.read(9))
            if op == _CHUNK:
                _seal_chunk(f, pos + 9)
            pos += 9 + length
        value = _crc(f, 0, at)  # a genuine 0 (1 in 2**32) reads as "not computed": unchecked
        f.seek(at + 9)
        f.write(struct.pack("<I", value))


def _seal_chunk(f: BinaryIO, body: int) -> None:
    f.seek(body + 16)
    usize, crc, clen = struct.unpack("<QII", f.read(16))
    compression = f.read(clen)
    records_len = struct.unpack("<Q", f.read(8))[0]
    if crc or compression or records_len != usize:
        return  # computed already, or compressed (not what slimseg writes)
    value = _crc(f, body + 16 + 16 + clen + 8, records_len)
    f.seek(body + 24)
    f.write(struct.pack("<I", value))
