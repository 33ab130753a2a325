"""MCAP logs of JSON messages with JSON Schemas, written with the official ``mcap`` library.

``McapLog`` is a context manager: whatever ends the run (normal completion, an exception,
Ctrl-C), leaving the ``with`` block finishes the file, so the chunks written so far, their message
indexes and the summary section are on disk and the file is valid. Files are chunked,
zstd-compressed and fully indexed (viewers built on the TypeScript reader need message indexes).

Nothing wall-clock goes into the file (attachment times are simulated times), so a deterministic
run writes a byte-identical log.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import orjson
import zstandard
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer

from cosim import __version__
from cosim.errors import LogError

_JSON_OPTIONS = orjson.OPT_SERIALIZE_NUMPY


#: What the mcap reader raises on truncated or corrupted input.
READ_ERRORS = (McapError, ValueError, EOFError, struct.error, zstandard.ZstdError)


def dumps(payload: Any) -> bytes:
    """JSON bytes of a message. NaN and ±inf become null (JSON has no such numbers)."""
    return orjson.dumps(payload, option=_JSON_OPTIONS)


class McapLog:
    """Writes JSON messages on named topics, each with a JSON Schema, into one MCAP file."""

    def __init__(self, path: str | Path, *, chunk_size: int = 512 * 1024) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stream: IO[bytes] = open(self.path, "wb")
        self._writer = Writer(self._stream, chunk_size=chunk_size, compression=CompressionType.ZSTD, index_types=IndexType.ALL)
        self._writer.start(profile="", library=f"cosim/{__version__}")
        self._channels: dict[str, int] = {}
        self._sequence: dict[int, int] = {}
        self.messages = 0
        self.closed = False

    def __enter__(self) -> McapLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def channel(self, topic: str, schema: dict[str, Any]) -> int:
        """Register a topic with its JSON Schema (once); returns its channel id."""
        if topic in self._channels:
            return self._channels[topic]
        title = schema.get("title", topic)
        schema_id = self._writer.register_schema(name=title, encoding="jsonschema", data=json.dumps(schema).encode())
        channel_id = self._writer.register_channel(topic=topic, message_encoding="json", schema_id=schema_id)
        self._channels[topic] = channel_id
        self._sequence[channel_id] = 0
        return channel_id

    def write(self, channel_id: int, time_ns: int, payload: Any) -> None:
        """Append one message; ``time_ns`` is simulated time (log and publish time)."""
        sequence = self._sequence[channel_id]
        self._sequence[channel_id] = sequence + 1
        self._writer.add_message(channel_id, log_time=time_ns, data=dumps(payload), publish_time=time_ns, sequence=sequence)
        self.messages += 1

    def metadata(self, name: str, values: dict[str, str]) -> None:
        self._writer.add_metadata(name, {key: str(value) for key, value in values.items()})

    def attach(self, name: str, media_type: str, data: bytes, time_ns: int = 0) -> None:
        self._writer.add_attachment(create_time=time_ns, log_time=time_ns, name=name, media_type=media_type, data=data)

    def close(self) -> None:
        """Write the last chunk, the indexes and the summary; idempotent."""
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.finish()
        finally:
            self._stream.close()


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


class LogReader:
    """Reads a cosim (or any JSON-encoded) MCAP log, with clear errors for unreadable files."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise LogError(f"{self.path}: no such file")
        self._stream = open(self.path, "rb")
        try:
            self._reader = make_reader(self._stream)
            self.header = self._reader.get_header()
        except READ_ERRORS as error:
            self._stream.close()
            raise LogError(f"{self.path}: not a readable MCAP file ({error})") from None

    def __enter__(self) -> LogReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self._stream.close()

    def summary(self):  # mcap.records.Summary | None
        """The summary section, or None when the file has none (e.g. the writer was killed)."""
        try:
            return self._reader.get_summary()
        except READ_ERRORS:
            return None

    def metadata(self) -> dict[str, dict[str, str]]:
        try:
            return {record.name: dict(record.metadata) for record in self._reader.iter_metadata()}
        except READ_ERRORS:
            return {}

    def attachments(self) -> dict[str, bytes]:
        try:
            return {record.name: bytes(record.data) for record in self._reader.iter_attachments()}
        except READ_ERRORS:
            return {}

    def messages(self, topics: list[str] | None = None) -> Iterator[tuple[str, int, dict[str, Any]]]:
        """(topic, log_time_ns, decoded JSON) in file order, optionally only some topics."""
        try:
            for _schema, channel, message in self._reader.iter_messages(topics=topics, log_time_order=False):
                yield channel.topic, message.log_time, orjson.loads(message.data)
        except READ_ERRORS as error:
            raise LogError(f"{self.path}: the log is damaged after this point ({error})") from None
