"""What ``mcap info`` tells of an MCAP file, as one JSON-ready value: for any file, cosim's or not."""

from __future__ import annotations

from typing import Any

from cosim.log.reader import LogReader


def file_info(reader: LogReader) -> dict[str, Any]:
    """The file's writer (library, profile), its messages (count, first and last log time), its
    chunks per compression, its channels (topic, message encoding, schema name and encoding,
    metadata, message count), attachments (name, media type, size, times) and metadata records.
    Counts and times come from the summary's statistics, else from reading every message."""
    header = reader.header()
    span = reader.span()
    schemas = reader.schema_records()
    channels = []
    for cid, channel in reader.channels().items():
        schema = schemas.get(channel.schema_id)
        channels.append(
            {
                "id": cid,
                "topic": channel.topic,
                "message_encoding": channel.message_encoding,
                "schema": None if schema is None else schema.name,
                "schema_encoding": None if schema is None else schema.encoding,
                "messages": span.counts.get(cid, 0),
                "metadata": dict(channel.metadata),
            }
        )
    chunks: dict[str, dict[str, int]] = {}
    summary = reader.summary()
    for index in summary.chunk_indexes if summary is not None else []:
        entry = chunks.setdefault(index.compression or "none", {"chunks": 0, "compressed": 0, "uncompressed": 0})
        entry["chunks"] += 1
        entry["compressed"] += index.compressed_size
        entry["uncompressed"] += index.uncompressed_size
    return {
        "library": None if header is None else header.library,
        "profile": None if header is None else header.profile,
        "messages": span.messages,
        "start_ns": span.start_ns,
        "end_ns": span.end_ns,
        "chunks": chunks,
        "channels": channels,
        "attachments": [
            {
                "name": a.name,
                "media_type": a.media_type,
                "bytes": len(a.data),
                "log_time_ns": a.log_time,
                "create_time_ns": a.create_time,
            }
            for a in reader.attachment_records()
        ],
        "metadata": [{"name": m.name, "metadata": dict(m.metadata)} for m in reader.metadata_records()],
    }
