"""Reading MCAP files, cosim's logs and any other, damaged ones included: as far as they go, with
what was wrong said.

``LogReader`` reads the summary and its indexes where they are intact (their CRC checked), and
otherwise scans the records in file order (``cosim.log.scan`` reads each within its bytes). A
damaged chunk is skipped, a damaged attachment left out, and a scan stops at the first record that
cannot be framed; each says where in ``warnings``. Channels and schemas that the summary does not
repeat are found by a scan. Only a file that is not MCAP at all raises.
"""

from __future__ import annotations

import json
import struct
import zlib
from collections import Counter
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import orjson
from mcap import records
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.summary import Summary
from mcap.well_known import MessageEncoding, SchemaEncoding

from cosim.errors import LogError
from cosim.log import scan
from cosim.log.scan import MESSAGE, RECORD, Damaged

#: What reading a damaged file may raise (Damaged, from ``cosim.log.scan``, is an McapError).
READ_ERRORS = (McapError, ValueError, EOFError, struct.error, OSError, OverflowError)

_MESSAGE_OPCODE = int(Opcode.MESSAGE)

Message = tuple[records.Schema | None, records.Channel, records.Message]
"""A message as mcap's readers yield it: its schema (None for none), its channel, the record."""


@dataclass(frozen=True)
class Span:
    """How many messages a file holds per channel id, and the log times of the first and last."""

    counts: dict[int, int]
    messages: int
    start_ns: int | None
    end_ns: int | None


class LogReader:
    """Reads an MCAP file: cosim's logs (JSON messages) and any other.

    Damage never raises past the first readable byte: a file without a summary section (its
    writer was killed, or it was cut) or with a damaged one is read sequentially, and reading
    stops at the first record that cannot be read, with a warning in ``warnings`` that says where.
    Only a file that is not an MCAP file at all raises LogError.
    """

    MAGIC = scan.MAGIC

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise LogError(f"{self.path}: no such file")
        if self.path.is_dir():
            raise LogError(f"{self.path}: is a directory, not an MCAP file")
        self.warnings: list[str] = []
        self._stream = open(self.path, "rb")
        if self._stream.read(len(self.MAGIC)) != self.MAGIC:
            self._stream.close()
            raise LogError(f"{self.path}: not a readable MCAP file (it does not start with the MCAP magic bytes)")
        self._file = scan.McapFile(self._stream)
        self.finished = True
        """Whether the file ends with its footer (a writer that was killed, or a cut, leaves none)."""
        try:
            self._summary = scan.summary(self._file)
        except scan.Cut:
            self._summary, self.finished = None, False
            self.warn(
                "the file has no summary section (its writer did not finish: killed, or the file was cut); "
                "it is read sequentially up to the first damaged record"
            )
        except Damaged as error:
            self._summary = None
            self.warn(f"the file's summary section is damaged ({error}); the file is read sequentially")
        self._channels: dict[int, records.Channel] = {}
        self._schemas: dict[int, records.Schema] = {}
        self._catalogued = False
        if self._summary is not None:
            self._channels, self._schemas = dict(self._summary.channels), dict(self._summary.schemas)
            self._catalogued = _lists_every_channel(self._summary)
        self._span: Span | None = None

    def __enter__(self) -> LogReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self._stream.close()

    def warn(self, text: str) -> None:
        """Add a warning, once."""
        if text not in self.warnings:
            self.warnings.append(text)

    def summary(self) -> Summary | None:
        """The summary section, or None when the file has none or it is damaged."""
        return self._summary

    def header(self) -> records.Header | None:
        """The file's Header record (library, profile), or None where it is damaged."""
        try:
            opcode, body = self._file.record(len(self.MAGIC), Opcode.HEADER)
            return scan.parse(opcode, body, len(self.MAGIC))
        except Damaged:
            return None

    # -- channels and schemas

    def channels(self) -> dict[int, records.Channel]:
        """Every channel by id: from the summary, or found by a scan where it does not list them all."""
        self._catalogue()
        return dict(sorted(self._channels.items()))

    def schema_records(self) -> dict[int, records.Schema]:
        """Every schema by id, found as the channels are."""
        self._catalogue()
        return dict(sorted(self._schemas.items()))

    def schemas(self) -> dict[str, dict[str, Any]]:
        """Topic → its JSON Schema (parsed), in channel order. Topics without a JSON Schema map to {}."""

        def parsed(schema_id: int) -> dict[str, Any]:
            schema = self._schemas.get(schema_id)
            if schema is None or schema.encoding != SchemaEncoding.JSONSchema:
                return {}
            try:
                value = json.loads(schema.data)
            except ValueError:
                return {}
            return value if isinstance(value, dict) else {}

        return {channel.topic: parsed(channel.schema_id) for channel in self.channels().values()}

    def _catalogue(self) -> None:
        """Fill in the channels and schemas the summary does not list, by a scan (once)."""
        if self._catalogued:
            return
        self._catalogued = True
        try:
            for _, record in self.scan({Opcode.SCHEMA, Opcode.CHANNEL}, chunks=True):
                self._register(record)
        except Damaged:
            pass  # read as far as the file goes; ``messages`` says where it stops

    def _register(self, record: records.Schema | records.Channel) -> None:
        if isinstance(record, records.Schema):
            self._schemas.setdefault(record.id, record)
        else:
            self._channels.setdefault(record.id, record)

    # -- metadata and attachments

    def metadata(self) -> dict[str, dict[str, str]]:
        return {record.name: dict(record.metadata) for record in self.metadata_records()}

    def metadata_records(self) -> list[records.Metadata]:
        """The Metadata records in file order: through the summary's index where it lists them all,
        else by a scan."""
        return self._indexed_or_scanned(Opcode.METADATA, "metadata_indexes", "metadata_count")

    def attachments(self) -> dict[str, bytes]:
        """The intact attachments by name. One whose CRC does not match its bytes is left out, with a
        warning naming it."""
        return {record.name: bytes(record.data) for record in self.attachment_records()}

    def attachment_records(self) -> list[records.Attachment]:
        """The intact Attachment records in file order, found as the metadata are."""
        return self._indexed_or_scanned(Opcode.ATTACHMENT, "attachment_indexes", "attachment_count")

    def _indexed_or_scanned(self, opcode: int, indexes: str, count: str) -> list[Any]:
        summary, found = self._summary, []
        listed = [] if summary is None else getattr(summary, indexes)
        if summary is not None and (
            listed if summary.statistics is None else getattr(summary.statistics, count) == len(listed)
        ):
            for index in sorted(listed, key=lambda i: i.offset):
                try:
                    found.append(
                        scan.parse(opcode, self._file.record(index.offset, opcode, index.length)[1], index.offset)
                    )
                except Damaged as error:
                    self.warn(str(error))
            return found
        try:
            for _, record in self.scan({opcode}, chunks=False):
                found.append(record)
        except Damaged:
            pass  # the records before the damage; ``messages`` says where it is
        return found

    # -- messages

    def messages(self, topics: list[str] | None = None) -> Iterator[tuple[str, int, Any]]:
        """(topic, log_time_ns, decoded JSON) in file order, optionally only some topics: the messages
        of JSON channels (cosim's); the others are not decoded (a warning names their topics), nor is
        a payload that is not JSON (a warning names its topic and time). Stops, with a warning, at
        the first record that cannot be read."""
        if topics is not None:
            self._catalogue()
        decoded: dict[int, str | None] = {}  # channel id -> its topic, None for a channel not decoded
        undecoded: Counter[str] = Counter()  # "topic (encoding)" -> messages of a wanted topic not decoded
        not_json: dict[int, str] = {}  # such a channel's id -> its "topic (encoding)"
        count, last, loads = 0, None, orjson.loads
        try:
            for channel_id, message in self._messages(topics):
                topic = decoded.get(channel_id)
                if topic is None:
                    if channel_id not in decoded:
                        topic = decoded[channel_id] = self._decoded_topic(channel_id, topics, not_json)
                    if topic is None:
                        if channel_id in not_json:
                            undecoded[not_json[channel_id]] += 1
                        continue
                try:
                    payload = loads(message.data)
                except orjson.JSONDecodeError as error:
                    self.undecodable(topic, message.log_time, error)
                    continue
                last = message.log_time
                count += 1
                yield topic, last, payload
        except READ_ERRORS as error:
            self._stopped(error, count, last)
        finally:
            if undecoded:
                listed = ", ".join(f"{topic}: {n}" for topic, n in undecoded.items())
                self.warn(f"messages that are not JSON were not decoded (cosim reads JSON messages): {listed}")

    def undecodable(self, topic: str, log_time: int, error: Exception) -> None:
        """Say that a message on a JSON channel is not JSON (it is skipped)."""
        self.warn(f"{topic}: the message at t = {log_time / 1e9:g} s is not valid JSON ({error}); skipped")

    def _stopped(self, error: Exception, count: int, last: int | None) -> None:
        where = "at its start" if last is None else f"after t = {last / 1e9:g} s"
        reason = str(error) or type(error).__name__
        self.warn(f"the log is damaged or cut {where} ({reason}); the {count} messages before it were read")

    def _decoded_topic(self, channel_id: int, topics: list[str] | None, not_json: dict[int, str]) -> str | None:
        """The topic of a channel whose messages ``messages`` decodes, None for one it does not; one
        of a wanted topic that is not JSON goes into ``not_json``."""
        channel = self._channels.get(channel_id)
        if channel is None:
            self.warn(f"messages on channel {channel_id}, which the file never declares, were skipped")
            return None
        if topics is not None and channel.topic not in topics:
            return None
        if channel.message_encoding != MessageEncoding.JSON:
            not_json[channel_id] = f"{channel.topic} ({channel.message_encoding or 'no encoding'})"
            return None
        return channel.topic

    def raw_messages(self, topics: list[str] | None = None) -> Iterator[Message]:
        """(schema, channel, message record) in file order, as mcap's readers yield them, for any
        encoding. Stops, with a warning, at the first record that cannot be read; a message on a
        channel the file never declares is skipped with a warning."""
        if topics is not None:
            self._catalogue()
        count, last = 0, None
        try:
            for channel_id, message in self._messages(topics):
                channel = self._channels.get(channel_id)
                if channel is None:
                    self.warn(f"messages on channel {channel_id}, which the file never declares, were skipped")
                    continue
                if topics is None or channel.topic in topics:
                    count, last = count + 1, message.log_time
                    yield self._schemas.get(channel.schema_id), channel, message
        except READ_ERRORS as error:
            self._stopped(error, count, last)

    def _messages(self, topics: list[str] | None) -> Iterator[tuple[int, records.Message]]:
        """(channel id, message) in file order: chunk by chunk through the chunk index where the
        summary has one (``topics``: chunks without them are skipped), else by a scan."""
        if self._summary is None or not self._summary.chunk_indexes:
            for _, record in self.scan({Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE}, chunks=True):
                if isinstance(record, records.Message):
                    yield record.channel_id, record
                else:
                    self._register(record)
            return
        wanted = None
        if topics is not None and self._catalogued:
            wanted = {cid for cid, channel in self._channels.items() if channel.topic in topics}
        for index in sorted(self._summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            if (
                wanted is not None
                and index.message_index_offsets
                and not wanted.intersection(index.message_index_offsets)
            ):
                continue
            chunk = self._chunk(index)
            yield from (chunk if wanted is None else [item for item in chunk if item[0] in wanted])

    def _chunk(self, index: records.ChunkIndex) -> list[tuple[int, records.Message]]:
        """The messages of the chunk an index points at; one that is damaged is skipped with a warning,
        one whose message indexes do not match it is read with a warning."""
        at, length = index.chunk_start_offset, index.chunk_length
        try:
            _, body = self._file.record(at, Opcode.CHUNK, length)
            _, data = scan.chunk_data(body, at)
            messages, offsets = self._chunk_messages(data, at)
            damage = _index_damage(index, self._file, offsets)
        except Damaged as error:
            self.warn(
                f"a damaged chunk was skipped: bytes {at}-{at + length}, "
                f"t = {index.message_start_time / 1e9:g}-{index.message_end_time / 1e9:g} s ({error})"
            )
            return []
        if damage is not None:
            self.warn(
                f"the chunk at bytes {at}-{at + length} "
                f"(t = {index.message_start_time / 1e9:g}-{index.message_end_time / 1e9:g} s) is intact but "
                f"{damage}: readers that seek by them may miss or misplace messages ('cosim recover' rewrites them)"
            )
        return messages

    def _chunk_messages(
        self, data: bytes, at: int
    ) -> tuple[list[tuple[int, records.Message]], dict[int, tuple[int, int]]]:
        """The messages in a chunk's records, and where each sits: offset -> (channel id, log time);
        the schemas and channels in it are registered.

        Messages are read with one ``unpack_from`` each (the MCAP specification's Message layout)
        rather than mcap's field-by-field stream reads: ``cosim.analysis.metrics.measure`` of the
        default run's log takes 14 % less time."""
        messages: list[tuple[int, records.Message]] = []
        offsets: dict[int, tuple[int, int]] = {}
        head, fields, message = RECORD.unpack_from, MESSAGE.unpack_from, records.Message  # the loop's calls
        offset, size = 0, len(data)
        while offset < size:
            if offset + RECORD.size > size:
                raise Damaged(f"the Chunk at byte {at} ends inside a record's header")
            opcode, length = head(data, offset)
            start = offset + RECORD.size
            end = start + length
            if end > size:
                raise Damaged(f"a record at byte {offset} of the Chunk at byte {at} runs past the chunk's end")
            if opcode == _MESSAGE_OPCODE:
                if length < MESSAGE.size:
                    raise Damaged(f"a message record at byte {offset} of the Chunk at byte {at} is too short")
                channel_id, sequence, log_time, publish_time = fields(data, start)
                messages.append(
                    (
                        channel_id,
                        message(channel_id, log_time, data[start + MESSAGE.size : end], publish_time, sequence),
                    )
                )
                offsets[offset] = (channel_id, log_time)
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                self._register(scan.parse(opcode, data[start:end], at))
            offset = end
        return messages, offsets

    def scan(self, opcodes: Collection[int], chunks: bool = True) -> Iterator[tuple[int, Any]]:
        """(offset, record) of the records of these opcodes in file order, inside the chunks too
        when ``chunks``; a damaged chunk is skipped with a warning. Reading every byte then, it
        checks the data section's CRC at its end. Raises Damaged where a record cannot be framed."""
        crc = zlib.crc32(self.MAGIC)
        for offset, opcode, length in self._file.walk():
            if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                if chunks and opcode == Opcode.DATA_END:
                    self._check_data_crc(offset, length, crc)
                return
            if not chunks and opcode not in opcodes:
                continue
            raw = self._file.bytes_at(offset, RECORD.size + length, "a record")
            crc = zlib.crc32(raw, crc)
            body = raw[RECORD.size :]
            if opcode == Opcode.CHUNK and chunks:
                try:
                    _, data = scan.chunk_data(body, offset)
                    for inner, code, start, end in scan.inner(data, offset):
                        if code in opcodes:
                            yield offset + inner, scan.parse(code, data[start:end], offset)
                except Damaged as error:
                    self.warn(f"a damaged chunk was skipped: bytes {offset}-{offset + RECORD.size + length} ({error})")
            elif opcode in opcodes:
                try:
                    record = scan.parse(opcode, body, offset)
                except Damaged as error:  # framed: the records after it are read
                    self.warn(f"{error}; skipped")
                    continue
                yield offset, record

    def _check_data_crc(self, offset: int, length: int, crc: int) -> None:
        try:
            (stored,) = struct.unpack_from("<I", self._file.bytes_at(offset + RECORD.size, length, "DataEnd"))
        except (Damaged, struct.error):
            return
        if stored != 0 and stored != crc:
            self.warn(
                "the data section does not match its CRC: a record outside the chunks is damaged "
                "(messages, metadata or attachments read from it may be wrong)"
            )

    # -- counts

    def summary_counts(self) -> dict[str, int] | None:
        """Messages per topic from the summary's statistics; None without them."""
        summary = self._summary
        if summary is None or summary.statistics is None:
            return None
        counts: dict[str, int] = {}
        for cid, channel in self.channels().items():
            counts[channel.topic] = counts.get(channel.topic, 0) + summary.statistics.channel_message_counts.get(cid, 0)
        return counts

    def span(self) -> Span:
        """Messages per channel and the first and last log time: from the statistics, else by reading
        every message (once)."""
        statistics = self._summary.statistics if self._summary is not None else None
        if statistics is not None:
            empty = statistics.message_count == 0
            return Span(
                dict(statistics.channel_message_counts),
                statistics.message_count,
                None if empty else statistics.message_start_time,
                None if empty else statistics.message_end_time,
            )
        if self._span is None:
            counts: Counter[int] = Counter()
            start = end = None
            for _, channel, message in self.raw_messages():
                counts[channel.id] += 1
                start = message.log_time if start is None else min(start, message.log_time)
                end = message.log_time if end is None else max(end, message.log_time)
            self._span = Span(dict(counts), sum(counts.values()), start, end)
        return self._span

    def message_counts(self) -> dict[str, int]:
        """Messages per topic, every channel listed."""
        counts = dict.fromkeys((c.topic for c in self.channels().values()), 0)
        for cid, n in self.span().counts.items():
            channel = self._channels.get(cid)
            if channel is not None:
                counts[channel.topic] += n
        return counts


def _lists_every_channel(summary: Summary) -> bool:
    """Whether the summary repeats every channel and schema of the file, as far as it tells: those
    its statistics count and its indexes name (without statistics, at least one)."""
    named = set(summary.statistics.channel_message_counts) if summary.statistics is not None else set()
    for index in summary.chunk_indexes:
        named.update(index.message_index_offsets)
    if not named <= summary.channels.keys():
        return False
    if any(c.schema_id != 0 and c.schema_id not in summary.schemas for c in summary.channels.values()):
        return False
    if summary.statistics is not None:
        return summary.statistics.channel_count == len(summary.channels)
    return bool(summary.channels)


_INDEX_HEADER = struct.Struct("<HI")  # a MessageIndex record's channel id and its entries' byte length
_INDEX_ENTRY = struct.Struct("<QQ")  # one entry: log time, offset in the chunk's uncompressed records


def _index_damage(index: records.ChunkIndex, file: scan.McapFile, offsets: dict[int, tuple[int, int]]) -> str | None:
    """What is wrong with a chunk's message indexes (the records after it), or None.

    The format gives them no CRC: each entry is checked against the message it points at. The
    records are read with ``struct`` (the MCAP specification's MessageIndex layout: channel id, the
    entries' byte length, then (log time, offset) pairs), not entry by entry through mcap's stream."""
    if index.message_index_length == 0 and not index.message_index_offsets:
        return None  # the writer wrote none (they are optional)
    entries = bad = 0
    position = 0
    try:
        data = file.bytes_at(
            index.chunk_start_offset + index.chunk_length, index.message_index_length, "message indexes"
        )
        while position < len(data):
            opcode, record_length = RECORD.unpack_from(data, position)
            start = position + RECORD.size
            position = start + record_length
            if position > len(data):
                raise EOFError(f"a record runs {position - len(data)} bytes past the message indexes")
            if opcode != Opcode.MESSAGE_INDEX:
                continue
            channel_id, size = _INDEX_HEADER.unpack_from(data, start)
            if size % 16 or _INDEX_HEADER.size + size > record_length:
                raise McapError(f"a message index of {size} bytes in a record of {record_length}")
            pairs = _INDEX_ENTRY.iter_unpack(data[start + _INDEX_HEADER.size : start + _INDEX_HEADER.size + size])
            for log_time, offset in pairs:
                entries += 1
                bad += offsets.get(offset) != (channel_id, log_time)
    except (McapError, struct.error, EOFError, ValueError) as error:
        return f"its message indexes cannot be read ({error or type(error).__name__})"
    if entries != len(offsets):
        return f"its message indexes list {entries} messages, the chunk holds {len(offsets)}"
    if bad:
        return f"{bad} of its {entries} message index entries do not point at their message"
    return None
