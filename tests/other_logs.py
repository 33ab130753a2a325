"""Logs written by another program (the official ``mcap`` writer, JSON messages, no cosim
metadata): what the readers of cosim logs must take without failing."""

from __future__ import annotations

from pathlib import Path

from mcap.writer import Writer


def write_other_log(path: Path, messages: list[tuple[str, int, bytes]]) -> Path:
    """A log of ``messages`` in order, each (topic, log time in ns, JSON bytes); every topic with the
    JSON Schema of any object."""
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start()
        schema = writer.register_schema("x", "jsonschema", b'{"type":"object"}')
        channels: dict[str, int] = {}
        for topic, time_ns, data in messages:
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, "json", schema)
            writer.add_message(channels[topic], time_ns, data, time_ns)
        writer.finish()
    return path
