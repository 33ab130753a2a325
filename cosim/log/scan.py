"""An MCAP file's records, read within the bytes there are: damage is one exception that says where.

mcap's readers trust the lengths a file declares, so one flipped byte can make them allocate
gigabytes (``MemoryError``), seek outside the file (``OSError``, ``OverflowError``) or raise lz4's
``RuntimeError``. Here every length is checked against the bytes that hold it before anything is
read or allocated; each record is parsed by its fields within its declared length (the format lets
records grow at their end: what follows the fields is skipped), with mcap's record classes; a chunk
is decompressed to at most its declared size and checked against its CRC; the summary section is
checked against its CRC. Whatever is wrong raises ``Damaged``, naming the byte where it is.
"""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Iterator
from typing import Any, BinaryIO

import lz4.frame
import zstandard
from mcap import records
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.summary import Summary

MAGIC = b"\x89MCAP0\r\n"
RECORD = struct.Struct("<BQ")  # a record's opcode and the length of its body
MESSAGE = struct.Struct("<HIQQ")  # a Message record's channel id, sequence, log time and publish time
CHUNK = struct.Struct("<QQQII")  # a Chunk's start and end time, uncompressed size and CRC, compression length
FOOTER = struct.Struct("<QQI")  # summary start, summary offset start, summary CRC
FOOTER_RECORD = RECORD.size + FOOTER.size
PIECE = 1 << 22  # decompressed at most this much at a time: a damaged size allocates no more


class Damaged(McapError):
    """A record that cannot be read as the MCAP specification lays it out."""


class Cut(Damaged):
    """The file ends before its footer: inside a record, or without one (its writer stopped, or it
    was cut; a damaged length that reaches past the end reads the same)."""


#: The records parsed by mcap's record classes (Message and Chunk are read here, with ``struct``).
PARSERS: dict[int, Any] = {
    Opcode.HEADER: records.Header,
    Opcode.FOOTER: records.Footer,
    Opcode.SCHEMA: records.Schema,
    Opcode.CHANNEL: records.Channel,
    Opcode.ATTACHMENT: records.Attachment,
    Opcode.METADATA: records.Metadata,
    Opcode.STATISTICS: records.Statistics,
    Opcode.CHUNK_INDEX: records.ChunkIndex,
    Opcode.ATTACHMENT_INDEX: records.AttachmentIndex,
    Opcode.METADATA_INDEX: records.MetadataIndex,
    Opcode.DATA_END: records.DataEnd,
    Opcode.SUMMARY_OFFSET: records.SummaryOffset,
}
NAMES = {Opcode.MESSAGE: "Message", Opcode.CHUNK: "Chunk", **{op: cls.__name__ for op, cls in PARSERS.items()}}


class _Exact(io.BytesIO):
    """A record's body that refuses to read past its end (mcap's stream returns short reads)."""

    def read(self, size: int | None = -1) -> bytes:
        data = super().read(size)
        if size is not None and size >= 0 and len(data) != size:
            raise Damaged(f"a field of {size} bytes runs past the end of its record")
        return data


def parse(opcode: int, body: bytes, where: int) -> Any:
    """The record of this opcode in ``body`` (its fields; bytes after them are ignored), checked:
    an attachment against its CRC, a message for its fixed fields. ``where``: its offset, for errors."""
    if opcode == Opcode.MESSAGE:
        if len(body) < MESSAGE.size:
            raise Damaged(f"the Message record at byte {where} is {len(body)} bytes long, shorter than its fields")
        channel_id, sequence, log_time, publish_time = MESSAGE.unpack_from(body)
        return records.Message(channel_id, log_time, body[MESSAGE.size :], publish_time, sequence)
    stream = _Exact(body)
    try:
        record = PARSERS[opcode].read(ReadDataStream(stream))
    except (Damaged, struct.error, UnicodeDecodeError) as error:
        raise Damaged(f"the {NAMES[opcode]} record at byte {where} is damaged ({error})") from None
    if opcode == Opcode.ATTACHMENT:
        end = stream.tell()  # the CRC is the last field, not the record's last 4 bytes
        (crc,) = struct.unpack_from("<I", body, end - 4)
        if crc != 0 and crc != zlib.crc32(memoryview(body)[: end - 4]):
            raise Damaged(f"the attachment {record.name!r} is damaged (its bytes do not match their CRC)")
    return record


class McapFile:
    """Bounded reads of one MCAP file: nothing is read or allocated past its end."""

    def __init__(self, stream: BinaryIO) -> None:
        self.stream = stream
        self.size = stream.seek(0, io.SEEK_END)

    def bytes_at(self, offset: int, length: int, what: str) -> bytes:
        if offset < 0 or length < 0 or offset + length > self.size:
            raise Damaged(f"{what} at byte {offset} ({length} bytes) runs past the end of the file ({self.size} bytes)")
        self.stream.seek(offset)
        return self.stream.read(length)

    def head(self, offset: int) -> tuple[int, int]:
        """The opcode and body length of the record at ``offset``, its body checked to fit."""
        if offset + RECORD.size > self.size:
            raise Cut(f"the file ends {self.size - offset} bytes into the record at byte {offset}")
        opcode, length = RECORD.unpack(self.bytes_at(offset, RECORD.size, "a record"))
        if offset + RECORD.size + length > self.size:
            name = NAMES.get(opcode, f"record (opcode {opcode:#04x})")
            raise Cut(
                f"the file ends inside the {name} at byte {offset} ({length} bytes long, {self.size} in the file)"
            )
        return opcode, length

    def record(self, offset: int, opcode: int | None = None, length: int | None = None) -> tuple[int, bytes]:
        """The opcode and body of the record at ``offset``; ``opcode`` and ``length`` (of the whole
        record) as an index says it is, checked."""
        found, body_length = self.head(offset)
        if opcode is not None and found != opcode:
            raise Damaged(f"the index points at byte {offset}, where there is no {NAMES[opcode]} record")
        if length is not None and length != RECORD.size + body_length:
            raise Damaged(f"the {NAMES[found]} record at byte {offset} is not as long as its index says")
        return found, self.bytes_at(offset + RECORD.size, body_length, "a record")

    def walk(self, start: int = len(MAGIC)) -> Iterator[tuple[int, int, int]]:
        """(offset, opcode, body length) of each record from ``start`` to the footer, bodies unread;
        raises Damaged where a record does not fit, and at an end without a footer."""
        offset = start
        while offset < self.size:
            opcode, length = self.head(offset)
            yield offset, opcode, length
            if opcode == Opcode.FOOTER:
                return
            offset += RECORD.size + length
        raise Cut(f"the file ends at byte {self.size} without its footer (its writer stopped, or it was cut)")


def chunk_data(body: bytes, where: int) -> tuple[records.Chunk, bytes]:
    """A Chunk record's fields (``data`` left empty) and its records, decompressed and checked."""
    try:
        start, end, size, crc, name_length = CHUNK.unpack_from(body)
        name_end = CHUNK.size + name_length
        compression = body[CHUNK.size : name_end].decode()
        (data_length,) = struct.unpack_from("<Q", body, name_end)
    except (struct.error, UnicodeDecodeError) as error:
        raise Damaged(f"the Chunk record at byte {where} is damaged ({error})") from None
    data_start = name_end + 8
    if data_start + data_length > len(body):
        raise Damaged(f"the Chunk record at byte {where} declares more data than it holds")
    chunk = records.Chunk(compression, b"", end, start, crc, size)
    data = decompress(compression, memoryview(body)[data_start : data_start + data_length], size, where)
    if crc != 0 and zlib.crc32(data) != crc:
        raise Damaged(f"the Chunk at byte {where} is damaged (its records do not match their CRC)")
    return chunk, data


def decompress(compression: str, data: memoryview, size: int, where: int) -> bytes:
    """A chunk's records: ``data`` decompressed to its declared ``size``, in pieces, so that a
    damaged size or stream allocates no more than the output there is (at most ``size`` + 1)."""
    if compression == "":
        out = bytes(data)
    elif compression in ("zstd", "lz4"):
        pieces, total = [], 0
        try:
            if compression == "zstd":
                reader = zstandard.ZstdDecompressor().stream_reader(data)
                while total <= size and (piece := reader.read(min(PIECE, size + 1 - total))):
                    pieces.append(piece)
                    total += len(piece)
            else:
                lz4_reader = lz4.frame.LZ4FrameDecompressor()
                piece = lz4_reader.decompress(data, max_length=min(PIECE, size + 1))
                while piece:
                    pieces.append(piece)
                    total += len(piece)
                    if lz4_reader.needs_input or total > size:
                        break
                    piece = lz4_reader.decompress(b"", max_length=min(PIECE, size + 1 - total))
        except (zstandard.ZstdError, RuntimeError, ValueError) as error:  # lz4 raises RuntimeError
            raise Damaged(f"the Chunk at byte {where} does not decompress ({compression}: {error})") from None
        out = pieces[0] if len(pieces) == 1 else b"".join(pieces)
    else:
        raise Damaged(f"the Chunk at byte {where} is compressed with {compression!r}, which cosim cannot read")
    if len(out) != size:
        raise Damaged(f"the Chunk at byte {where} holds {len(out)} bytes of records where it declares {size}")
    return out


def inner(data: bytes, where: int) -> Iterator[tuple[int, int, int, int]]:
    """(offset, opcode, body start, body end) of each record in a chunk's decompressed ``data``."""
    offset, size = 0, len(data)
    while offset < size:
        if offset + RECORD.size > size:
            raise Damaged(f"the Chunk at byte {where} ends inside a record's header")
        opcode, length = RECORD.unpack_from(data, offset)
        start = offset + RECORD.size
        if start + length > size:
            raise Damaged(f"a record at byte {offset} of the Chunk at byte {where} runs past the chunk's end")
        yield offset, opcode, start, start + length
        offset = start + length


def footer(file: McapFile) -> records.Footer:
    """The footer, or Damaged when the file does not end with one (its writer stopped, or it was cut)."""
    at = file.size - FOOTER_RECORD - len(MAGIC)
    if at < len(MAGIC) or file.bytes_at(file.size - len(MAGIC), len(MAGIC), "the magic") != MAGIC:
        raise Cut("the file does not end with the MCAP magic bytes")
    opcode, length = RECORD.unpack(file.bytes_at(at, RECORD.size, "the footer"))
    if opcode != Opcode.FOOTER or length != FOOTER.size:
        raise Cut(f"the file does not end with a footer record (at byte {at})")
    start, offsets_start, crc = FOOTER.unpack(file.bytes_at(at + RECORD.size, FOOTER.size, "the footer"))
    return records.Footer(summary_start=start, summary_offset_start=offsets_start, summary_crc=crc)


def summary(file: McapFile) -> Summary | None:
    """The summary section (None when the file has none), checked against its CRC; Damaged when
    it is damaged or the file has no footer."""
    end = file.size - FOOTER_RECORD - len(MAGIC)
    found = footer(file)
    if found.summary_start == 0:
        return None
    if not len(MAGIC) <= found.summary_start <= end:
        raise Damaged(f"the footer points at byte {found.summary_start} for the summary, outside the file")
    if found.summary_crc != 0:
        covered = file.bytes_at(found.summary_start, end + RECORD.size + 16 - found.summary_start, "the summary")
        if zlib.crc32(covered) != found.summary_crc:
            raise Damaged("the summary section is damaged (its bytes do not match their CRC)")
    result = Summary()
    for offset, opcode, length in file.walk(found.summary_start):
        if offset >= end:
            break
        if offset + RECORD.size + length > end:
            raise Damaged(f"the summary's record at byte {offset} runs into the footer")
        if opcode not in PARSERS or opcode == Opcode.SUMMARY_OFFSET:
            continue
        record = parse(opcode, file.bytes_at(offset + RECORD.size, length, "a record"), offset)
        if opcode == Opcode.SCHEMA:
            result.schemas[record.id] = record
        elif opcode == Opcode.CHANNEL:
            result.channels[record.id] = record
        elif opcode == Opcode.STATISTICS:
            result.statistics = record
        elif opcode == Opcode.CHUNK_INDEX:
            result.chunk_indexes.append(record)
        elif opcode == Opcode.ATTACHMENT_INDEX:
            result.attachment_indexes.append(record)
        elif opcode == Opcode.METADATA_INDEX:
            result.metadata_indexes.append(record)
    return result
