"""Recovering a log whose writer died: its records rewritten into a complete MCAP file.

A runner killed outright (SIGKILL, power loss) leaves an MCAP file without its summary section,
its message indexes for the last chunks and its footer: streaming readers read it, seeking readers
(``mcap``'s ``make_reader``, @mcap/core's indexed reader, Foxglove) do not. ``recover`` reads the
file's records in order, CRCs checked, up to the first damaged or cut one, and writes them with
the official writer into a new file (chunked, compressed, fully indexed, with its summary), like
rosbag2's reindex. It adds a ``cosim.recovered`` metadata record saying what it found; the run's
``cosim.result`` it cannot invent: a recovered log of a killed run has none, and
``cosim inspect`` says so.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from mcap import records
from mcap.opcode import Opcode
from mcap.writer import CompressionType, IndexType, Writer

from cosim import __version__
from cosim.errors import LogError
from cosim.files import temporary_beside
from cosim.log.reader import LogReader
from cosim.log.scan import Cut, Damaged

RECOVERED = "cosim.recovered"
COPIED = {Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.METADATA, Opcode.ATTACHMENT}


@dataclass
class Recovered:
    """What ``recover`` wrote: the file and how much of the original it holds."""

    path: Path
    messages: int = 0
    channels: int = 0
    metadata: int = 0
    attachments: int = 0
    last_time_ns: int | None = None
    damage: str = ""
    """Where reading stopped before the end of the file ("" if it read every record)."""
    bytes_read: int = 0
    bytes_total: int = 0
    warnings: list[str] = field(default_factory=list)


def recover(path: str | Path, out: str | Path | None = None) -> Recovered:
    """Rewrite the readable records of the log at ``path`` into ``out`` (default: the same file,
    replaced only once the new one is complete)."""
    source = Path(path)
    target = Path(out) if out is not None else source
    temporary = temporary_beside(target, ".recovering")
    result = Recovered(target, bytes_total=source.stat().st_size if source.is_file() else 0)
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    try:
        with LogReader(source) as reader, open(temporary, "wb") as sink:  # LogReader: one line for a non-MCAP file
            writer = Writer(sink, compression=CompressionType.ZSTD, index_types=IndexType.ALL)
            header = reader.header()
            library = f"cosim/{__version__} (recovered)"
            writer.start(
                profile=header.profile if header else "", library=(header.library if header else "") or library
            )
            try:
                declared = reader.channels(), reader.schema_records()  # the summary's, for a chunk lost
                for offset, record in reader.scan(COPIED):
                    if isinstance(record, records.Message) and record.channel_id not in channels:
                        _declare(writer, record.channel_id, declared, schemas, channels)
                    _copy(writer, record, schemas, channels, result)
                    result.bytes_read = offset
            except Cut as error:
                stopped = (
                    f"the file ends at byte {result.bytes_total} without its summary and footer (its writer stopped)"
                )
                if reader.finished:  # a damaged length, not an end
                    stopped = f"reading stopped after byte {result.bytes_read} of {result.bytes_total}: {error}"
                result.damage = stopped
            except Damaged as error:
                result.damage = f"reading stopped after byte {result.bytes_read} of {result.bytes_total}: {error}"
            result.warnings += reader.warnings
            writer.add_metadata(
                RECOVERED,
                {
                    "from": str(source),
                    "messages": str(result.messages),
                    "last_time_ns": str(result.last_time_ns),
                    "damage": result.damage or "none: every record was read",
                },
            )
            writer.finish()
        os.replace(temporary, target)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    result.channels = len(channels)
    return result


def _copy(writer: Writer, record: object, schemas: dict[int, int], channels: dict[int, int], result: Recovered) -> None:
    """One record of the original into the new file, ids renumbered as the writer assigns them."""
    if isinstance(record, records.Schema):
        if record.id not in schemas:
            schemas[record.id] = writer.register_schema(record.name, record.encoding, record.data)
    elif isinstance(record, records.Channel):
        if record.id not in channels:
            schema = schemas.get(record.schema_id, 0)
            channels[record.id] = writer.register_channel(
                record.topic, record.message_encoding, schema, dict(record.metadata)
            )
    elif isinstance(record, records.Message):
        channel = channels.get(record.channel_id)
        if channel is None:
            dropped = f"the messages on channel {record.channel_id}, which the file never declares, were dropped"
            if dropped not in result.warnings:
                result.warnings.append(dropped)
            return
        writer.add_message(channel, record.log_time, bytes(record.data), record.publish_time, record.sequence)
        result.messages += 1
        result.last_time_ns = (
            record.log_time if result.last_time_ns is None else max(result.last_time_ns, record.log_time)
        )
    elif isinstance(record, records.Metadata):
        if record.name != RECOVERED:
            writer.add_metadata(record.name, dict(record.metadata))
            result.metadata += 1
    elif isinstance(record, records.Attachment):
        writer.add_attachment(record.create_time, record.log_time, record.name, record.media_type, bytes(record.data))
        result.attachments += 1


def _declare(
    writer: Writer,
    channel_id: int,
    declared: tuple[dict[int, records.Channel], dict[int, records.Schema]],
    schemas: dict[int, int],
    channels: dict[int, int],
) -> None:
    """A channel (and its schema) that the records read so far do not declare (it was in a chunk
    that is lost) but the file's summary does."""
    channel = declared[0].get(channel_id)
    if channel is None:
        return
    schema = declared[1].get(channel.schema_id)
    if schema is not None:
        _copy(writer, schema, schemas, channels, Recovered(Path()))
    _copy(writer, channel, schemas, channels, Recovered(Path()))


def needs_recovery(path: str | Path) -> bool:
    """Whether seeking readers cannot open the file (it has no readable summary)."""
    try:
        with LogReader(path) as reader:
            return reader.summary() is None
    except LogError:
        return False
