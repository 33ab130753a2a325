"""MCAP logs of JSON messages with JSON Schemas, written with the official ``mcap`` library.

``McapLog`` is a context manager: whatever ends the run (normal completion, an exception,
Ctrl-C), leaving the ``with`` block finishes the file, so the chunks written so far, their message
indexes and the summary section are on disk and the file is valid. Files are chunked,
zstd-compressed and fully indexed (viewers built on the TypeScript reader need message indexes).

Nothing wall-clock goes into the file but what a caller writes (attachment times are simulated
times; a run records its start in its metadata), so a deterministic run writes the same log.

A ``LogSink`` may be handed to a log: every channel it registers, every message it writes (the
same JSON bytes), its metadata and attachments are teed to the sink as well, in the order the file
gets them. Two sinks: the live view (``cosim.log.live``) and the metrics scored while a run writes
its log (``cosim.analysis.metrics.LiveMeasurement``).

Messages take a shorter path into the chunk than the official writer's ``add_message`` (which builds
a ``Message`` record object and writes it field by field into a seekable buffer, about 20 Python
calls a message): ``_Writer`` packs the record's header in one ``struct`` call and appends it with
the data, and keeps the chunk's message index and the statistics as the official writer does. The
file is byte for byte the one the official writer writes (``tests/test_mcap_readers.py`` compares
them); everything else (chunks, compression, indexes, summary) is the official writer's own code.
"""

from __future__ import annotations

import json
import struct
from abc import ABC, abstractmethod
from pathlib import Path
from typing import IO, Any, Protocol, Self

import orjson
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, IndexType, Writer

from cosim import __version__
from cosim.files import open_output

_JSON_OPTIONS = orjson.OPT_SERIALIZE_NUMPY


def dumps(payload: Any) -> bytes:
    """JSON bytes of a message. NaN and ±inf become null (JSON has no such numbers)."""
    return orjson.dumps(payload, option=_JSON_OPTIONS)


def read_back(payload: Any) -> Any:
    """What a reader of the log gets for the message ``payload`` (``orjson.loads(dumps(payload))``),
    for a scorer that reads a run's messages as they are written. A flat dict of finite floats,
    64-bit integers, booleans and None, by ASCII names, reads back as it is (orjson writes a float as
    the shortest text that parses to the same double, -0.0 included): a copy is returned without the
    round trip, which costs microseconds a message; anything else goes through the bytes
    (``tests/test_topics.py``)."""
    if type(payload) is dict and all(_reads_back(key, value) for key, value in payload.items()):
        return dict(payload)
    return orjson.loads(dumps(payload))


def _reads_back(key: Any, value: Any) -> bool:
    """Whether a message's field is read back from its JSON as it is (orjson refuses keys other than
    strings, lone surrogates and integers beyond 64 bits; NaN and ±inf become null)."""
    if type(key) is not str or not key.isascii():
        return False
    kind = type(value)
    if kind is float:
        return value - value == 0.0
    if kind is int:
        return -(2**63) <= value < 2**64
    return value is None or kind is bool


class LogSink(Protocol):
    """Another consumer of what a log writes, in the file's order: channels, messages (simulated
    time), metadata records and attachments."""

    def channel(self, topic: str, schema: dict[str, Any]) -> Any:
        """A topic with its JSON Schema; returns the sink's handle for it."""

    def write(self, channel: Any, time_ns: int, data: bytes) -> None:
        """One message on a channel the sink returned: the JSON bytes the log writes."""

    def metadata(self, name: str, values: dict[str, str]) -> None:
        """A metadata record, as the log writes it."""

    def attach(self, name: str, media_type: str, data: bytes) -> None:
        """An attachment."""


#: A Message record's opcode, length, channel id, sequence, log time and publish time (MCAP spec).
_MESSAGE_HEADER = struct.Struct("<BQHIQQ")
_MESSAGE_FIELDS = _MESSAGE_HEADER.size - 9  # the record's length counts what follows opcode and length


class RecordSink(Protocol):
    """What takes a run's messages where no file is written (``SinkLog``): the records and payloads
    themselves, before their JSON, and only the time of those on topics it does not read."""

    def channel(self, topic: str, schema: dict[str, Any]) -> Any:
        """A topic with its JSON Schema; returns the sink's handle for it."""

    def reads(self, topic: str) -> bool:
        """Whether the sink looks into the messages of ``topic`` (else it is told their time only)."""

    def message(self, channel: Any, time_ns: int, payload: Any) -> None:
        """One message: the record (a ``cosim.log.topics`` dataclass) or the payload dict the log
        would have written as JSON."""

    def seen(self, channel: Any, time_ns: int) -> None:
        """A message on a topic the sink does not read, at simulated time ``time_ns``."""

    def metadata(self, name: str, values: dict[str, str]) -> None:
        """A metadata record, as a log would write it."""

    def attach(self, name: str, media_type: str, data: bytes) -> None:
        """An attachment."""


class _MessageIndex(MessageIndex):
    """A chunk's message index for one channel, written in one ``struct`` call (the same bytes)."""

    def write(self, stream: Any) -> None:
        records = self.records
        body = struct.pack(
            f"<BQHI{2 * len(records)}Q",
            Opcode.MESSAGE_INDEX,
            6 + 16 * len(records),
            self.channel_id,
            16 * len(records),
            *[value for record in records for value in record],
        )
        stream.write(body)


class _Writer(Writer):
    """The official MCAP writer, with a shorter path for a message into the chunk (same bytes)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # The writer's state a message updates (name-mangled attributes of mcap's Writer); where an
        # mcap release lays it out otherwise, messages take the official add_message.
        self._fast = all(
            hasattr(self, name) for name in ("_Writer__chunk_builder", "_Writer__statistics", "_Writer__chunk_size")
        )
        if self._fast:
            self._chunk = self._Writer__chunk_builder  # type: ignore[attr-defined]
            self._statistics = self._Writer__statistics  # type: ignore[attr-defined]
            self._chunk_size = self._Writer__chunk_size  # type: ignore[attr-defined]
            self._fast = self._chunk is not None and hasattr(self._chunk, "record_writer")

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0) -> None:
        if not self._fast:
            super().add_message(channel_id, log_time, data, publish_time, sequence)
            return
        statistics, chunk = self._statistics, self._chunk
        # the statistics and the chunk's time range and message index, as Writer and ChunkBuilder keep them
        if statistics.message_count == 0 or log_time < statistics.message_start_time:
            statistics.message_start_time = log_time
        if log_time > statistics.message_end_time:
            statistics.message_end_time = log_time
        statistics.channel_message_counts[channel_id] += 1
        statistics.message_count += 1
        if chunk.num_messages == 0 or log_time < chunk.message_start_time:
            chunk.message_start_time = log_time
        if log_time > chunk.message_end_time:
            chunk.message_end_time = log_time
        records = chunk.record_writer
        offset = records.count
        index = chunk.message_indices.get(channel_id)
        if index is None:
            index = chunk.message_indices[channel_id] = _MessageIndex(channel_id=channel_id, records=[])
        index.records.append((log_time, offset))
        chunk.num_messages += 1
        records.write(
            _MESSAGE_HEADER.pack(
                Opcode.MESSAGE, _MESSAGE_FIELDS + len(data), channel_id, sequence, log_time, publish_time
            )
            + data
        )
        if offset + _MESSAGE_HEADER.size + len(data) > self._chunk_size:
            self._Writer__finalize_chunk()  # type: ignore[attr-defined]


class _Log(ABC):
    """What a run's two logs share: a ``with`` block closes it, a topic is registered once."""

    _channels: dict[str, int]

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @abstractmethod
    def close(self) -> None:
        """Finish the log."""

    def channel(self, topic: str, schema: dict[str, Any]) -> int:
        """Register a topic with its JSON Schema (once); returns its channel id."""
        if topic not in self._channels:
            self._channels[topic] = self._register(topic, schema)
        return self._channels[topic]

    @abstractmethod
    def _register(self, topic: str, schema: dict[str, Any]) -> int:
        """Register a new topic; returns its channel id."""


class McapLog(_Log):
    """Writes JSON messages on named topics, each with a JSON Schema, into one MCAP file (and, with
    ``sink``, to the sink too)."""

    def __init__(self, path: str | Path, *, chunk_size: int = 512 * 1024, sink: LogSink | None = None) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stream: IO[bytes] = open_output(self.path)  # never through a link planted at the name
        self._writer = _Writer(
            self._stream, chunk_size=chunk_size, compression=CompressionType.ZSTD, index_types=IndexType.ALL
        )
        self._writer.start(profile="", library=f"cosim/{__version__}")
        self._channels: dict[str, int] = {}
        self._sequence: dict[int, int] = {}
        self.messages = 0
        self.closed = False
        self._sink = sink
        self._teed: dict[int, Any] = {}  # channel id -> the sink's channel

    def _register(self, topic: str, schema: dict[str, Any]) -> int:
        title = schema.get("title", topic)
        schema_id = self._writer.register_schema(
            name=title, encoding=SchemaEncoding.JSONSchema, data=json.dumps(schema).encode()
        )
        channel_id = self._writer.register_channel(
            topic=topic, message_encoding=MessageEncoding.JSON, schema_id=schema_id
        )
        self._sequence[channel_id] = 0
        if self._sink is not None:
            self._teed[channel_id] = self._sink.channel(topic, schema)
        return channel_id

    def reads(self, channel_id: int) -> bool:
        """A file keeps every message (``SinkLog`` may not)."""
        return True

    def seen(self, channel_id: int, time_ns: int) -> None:
        """For logs that may not keep a message (``SinkLog``): a file keeps every one."""
        raise TypeError("McapLog keeps every message: write it (its reads() is always True)")

    def write(self, channel_id: int, time_ns: int, payload: Any) -> None:
        """Append one message; ``time_ns`` is simulated time (log and publish time)."""
        sequence = self._sequence[channel_id]
        self._sequence[channel_id] = sequence + 1
        data = dumps(payload)
        self._writer.add_message(channel_id, log_time=time_ns, data=data, publish_time=time_ns, sequence=sequence)
        self.messages += 1
        if self._sink is not None:
            self._sink.write(self._teed[channel_id], time_ns, data)

    def flush(self) -> None:
        """Finish the chunk in progress and put everything written so far in the file: a writer
        killed outright afterwards loses nothing before this (``cosim recover`` rebuilds the rest)."""
        self._writer.flush()

    def metadata(self, name: str, values: dict[str, str]) -> None:
        record = {key: str(value) for key, value in values.items()}
        self._writer.add_metadata(name, record)
        if self._sink is not None:
            self._sink.metadata(name, record)

    def attach(self, name: str, media_type: str, data: bytes, time_ns: int = 0) -> None:
        self._writer.add_attachment(create_time=time_ns, log_time=time_ns, name=name, media_type=media_type, data=data)
        if self._sink is not None:
            self._sink.attach(name, media_type, data)

    def close(self) -> None:
        """Write the last chunk, the indexes and the summary; idempotent."""
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.finish()
        finally:
            self._stream.close()


class SinkLog(_Log):
    """A run's log that writes no file: what ``McapLog`` would write goes to ``sink`` alone, in the
    same order, as objects rather than JSON bytes (a campaign run whose log is not kept is scored
    so: ``cosim.analysis.metrics.LiveMeasurement``). ``reads(channel)`` tells a writer whether the
    sink looks into a channel's messages; one that does not may call ``seen`` instead of building
    the message. The channel ids are those an ``McapLog`` would give."""

    path: Path | None = None

    def __init__(self, sink: RecordSink) -> None:
        self._sink = sink
        self._channels: dict[str, int] = {}
        self._topics: list[str] = []
        self._handles: list[Any] = []
        # asked of the sink at a channel's first message: channels are registered before the run's
        # description is written, which is what the sink's answer may rest on
        self._reads: list[bool | None] = []
        self.messages = 0
        self.closed = False

    def _register(self, topic: str, schema: dict[str, Any]) -> int:
        channel_id = len(self._handles)
        self._topics.append(topic)
        self._handles.append(self._sink.channel(topic, schema))
        self._reads.append(None)
        return channel_id

    def reads(self, channel_id: int) -> bool:
        """Whether the sink looks into this channel's messages (asked when one is to be written)."""
        reads = self._reads[channel_id]
        if reads is None:
            reads = self._reads[channel_id] = self._sink.reads(self._topics[channel_id])
        return reads

    def write(self, channel_id: int, time_ns: int, payload: Any) -> None:
        self.messages += 1
        if self.reads(channel_id):
            self._sink.message(self._handles[channel_id], time_ns, payload)
        else:
            self._sink.seen(self._handles[channel_id], time_ns)

    def seen(self, channel_id: int, time_ns: int) -> None:
        """A message at ``time_ns`` on a channel the sink does not read (``reads`` is False): counted."""
        self.messages += 1
        self._sink.seen(self._handles[channel_id], time_ns)

    def flush(self) -> None:
        """Nothing to put on disk."""

    def metadata(self, name: str, values: dict[str, str]) -> None:
        self._sink.metadata(name, {key: str(value) for key, value in values.items()})

    def attach(self, name: str, media_type: str, data: bytes, time_ns: int = 0) -> None:
        self._sink.attach(name, media_type, data)

    def close(self) -> None:
        self.closed = True


def object_schema(title: str, properties: dict[str, Any], description: str = "") -> dict[str, Any]:
    """A JSON Schema for an object with the given properties (all required)."""
    schema: dict[str, Any] = {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": properties,
        "required": list(properties),
    }
    if description:
        schema["description"] = description
    return schema


def number(description: str = "", unit: str = "", nullable: bool = False) -> dict[str, Any]:
    """Schema of a number field (with its unit in the description); nullable for NaN/missing."""
    text = f"{description} [{unit}]" if unit else description
    schema: dict[str, Any] = {"type": ["number", "null"] if nullable else "number"}
    if text:
        schema["description"] = text
    return schema
