"""Damaged MCAP files of every compression (no compression, lz4, zstd): byte-flipped and cut copies,
made here at seeded positions from a conformance file and from a log of cosim, read by the reader,
``recover``, ``inspect``, ``export`` and ``plot``: what can be read is read, what cannot is said in
a line, and nothing raises but a LogError (the CLI's one line), never a traceback or MemoryError."""

from __future__ import annotations

import random
import struct
from pathlib import Path

import pytest
from mcap import records
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, IndexType, Writer

from cosim.cli import main
from cosim.errors import LogError
from cosim.log.info import file_info
from cosim.log.reader import LogReader
from cosim.log.recover import recover
from tests.test_mcap_conformance import SUITE

COMPRESSIONS = {"none": CompressionType.NONE, "lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD}


def rewrite(source: Path, target: Path, compression: CompressionType, chunk_size: int, until_s: float = 1e9) -> Path:
    """Every record of ``source`` (its messages until ``until_s``) written again by the official
    writer, chunked and compressed so."""
    with LogReader(source) as reader, open(target, "wb") as stream:
        writer = Writer(stream, chunk_size=chunk_size, compression=compression, index_types=IndexType.ALL)
        writer.start(profile="", library="tests")
        schemas = {
            sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in reader.schema_records().items()
        }
        channels = {
            cid: writer.register_channel(c.topic, c.message_encoding, schemas.get(c.schema_id, 0), dict(c.metadata))
            for cid, c in reader.channels().items()
        }
        for a in reader.attachment_records():  # first, as cosim writes them: a cut log keeps them
            writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        for name, values in reader.metadata().items():
            writer.add_metadata(name, values)
        for _, channel, m in reader.raw_messages():
            if m.log_time < until_s * 1e9:
                writer.add_message(channels[channel.id], m.log_time, m.data, m.publish_time, m.sequence)
        writer.finish()
        assert not reader.warnings
    return target


def foreign(folder: Path, compression: str) -> Path:
    """The conformance suite's ten messages (not JSON), an attachment and a metadata record, in chunks
    of two or three messages."""
    ten = SUITE / "TenMessages" / "TenMessages-ch-chx-mx-rch-rsh-st-sum.mcap"
    path = folder / f"foreign-{compression}.mcap"
    with LogReader(ten) as reader, open(path, "wb") as stream:
        writer = Writer(stream, chunk_size=90, compression=COMPRESSIONS[compression], index_types=IndexType.ALL)
        writer.start(profile="", library="tests")
        schema = writer.register_schema("Example", "c", b"\x04\x05\x06")
        channel = writer.register_channel("example", "a", schema, {"foo": "bar"})
        for _, _, m in reader.raw_messages():
            writer.add_message(channel, m.log_time, m.data, m.publish_time, m.sequence)
        writer.add_attachment(1, 2, "myFile", "application/octet-stream", bytes(range(40)))
        writer.add_metadata("myMetadata", {"foo": "bar"})
        writer.finish()
    return path


@pytest.fixture(scope="module")
def sources(default_run, tmp_path_factory) -> dict[str, Path]:
    """A foreign file and a log of cosim (the default run's first 0.25 s, in 4 KiB chunks) in each
    compression."""
    folder = tmp_path_factory.mktemp("damage")
    found = {f"foreign-{name}": foreign(folder, name) for name in COMPRESSIONS}
    for name, compression in COMPRESSIONS.items():
        found[f"cosim-{name}"] = rewrite(default_run.path, folder / f"cosim-{name}.mcap", compression, 4096, 0.25)
    return found


def chunks(path: Path) -> list[tuple[int, int, int]]:
    """(start offset, end offset, messages) of each chunk, by the official reader."""
    with open(path, "rb") as stream:
        summary = make_reader(stream).get_summary()
        assert summary is not None
        found = []
        for index in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            stream.seek(index.chunk_start_offset + 9)
            inner = breakup_chunk(records.Chunk.read(ReadDataStream(stream)))
            end = index.chunk_start_offset + index.chunk_length
            found.append((index.chunk_start_offset, end, sum(isinstance(r, records.Message) for r in inner)))
    return found


def read_everything(path: Path) -> tuple[list[tuple], dict[str, bytes], list[str]]:
    """Everything the reader gives of a file (messages as (topic, log time, data)), and its warnings."""
    with LogReader(path) as reader:
        reader.header(), reader.summary(), reader.schemas(), reader.metadata()
        attachments = reader.attachments()
        messages = [(c.topic, m.log_time, bytes(m.data)) for _, c, m in reader.raw_messages()]
        list(reader.messages())
        file_info(reader), reader.message_counts()
        assert all(isinstance(w, str) and "\n" not in w for w in reader.warnings)
        return messages, attachments, [w for w in reader.warnings if not w.startswith("messages that are not JSON")]


@pytest.mark.parametrize(
    "name", ["foreign-none", "foreign-lz4", "foreign-zstd", "cosim-none", "cosim-lz4", "cosim-zstd"]
)
def test_flipped_bytes_and_cuts_are_read_as_far_as_they_go(sources, name, tmp_path):
    source = sources[name]
    data = source.read_bytes()
    intact, attached, warnings = read_everything(source)
    assert warnings == [] and len(intact) >= 10 and attached
    spans = chunks(source)
    assert len(spans) >= 3 and sum(n for _, _, n in spans) == len(intact)
    rng = random.Random(name)
    damaged = tmp_path / "damaged.mcap"
    variants = [(k, rng.sample(range(8, len(data)), 1 if k < 24 else 3), None) for k in range(32)]
    variants += [(k, [], rng.randrange(8, len(data))) for k in range(12)]
    for k, flips, cut in variants:
        corrupt = bytearray(data[:cut])
        for at in flips:
            corrupt[at] ^= rng.randrange(1, 256)
        damaged.write_bytes(bytes(corrupt))
        try:
            messages, attachments, warnings = read_everything(damaged)
        except LogError:
            assert cut is not None and cut < 40 or any(at < 40 for at in flips), (name, k)  # the magic, the header
            continue
        if cut is not None:  # every chunk that ends before the cut is read
            assert messages == intact[: sum(n for _, end, n in spans if end <= cut)], (name, k, cut)
            assert warnings, (name, k, cut)
        elif len(flips) == 1:  # the chunk a byte is flipped in is lost at most, and nothing read is wrong
            assert len(messages) >= len(intact) - max(n for _, _, n in spans), (name, k, flips, warnings)
            assert set(messages) <= set(intact) and attachments.items() <= attached.items(), (name, k, flips)
        if (cut is not None or len(flips) == 1) and messages != intact:
            assert warnings, (name, k)
        result = recover(damaged, tmp_path / "recovered.mcap")
        with open(result.path, "rb") as stream:
            assert sum(1 for _ in make_reader(stream, validate_crcs=True).iter_messages()) == result.messages


def test_lengths_that_point_past_the_file_are_said_not_allocated(sources, tmp_path):
    """A chunk's uncompressed size or an attachment's length changed to petabytes: mcap's readers
    allocate them (MemoryError) or raise lz4's RuntimeError; ours says which record is damaged."""
    source = sources["foreign-lz4"]
    data = bytearray(source.read_bytes())
    with open(source, "rb") as stream:
        summary = make_reader(stream).get_summary()
    first = min(summary.chunk_indexes, key=lambda c: c.chunk_start_offset).chunk_start_offset
    (attachment,) = summary.attachment_indexes
    huge = bytearray(data)
    huge[first + 9 + 16 : first + 9 + 24] = struct.pack("<Q", 2**50)  # the first chunk's uncompressed size
    huge[attachment.offset + 1 : attachment.offset + 9] = struct.pack("<Q", 2**60)  # the attachment's length
    damaged = tmp_path / "huge.mcap"
    damaged.write_bytes(bytes(huge))
    messages, attachments, warnings = read_everything(damaged)
    assert len(messages) == 10 - chunks(source)[0][2] and attachments == {}
    assert any("a damaged chunk was skipped" in w and "declares" in w for w in warnings), warnings
    assert any("the file ends inside the Attachment" in w or "not as long as its index says" in w for w in warnings)
    result = recover(damaged, tmp_path / "recovered.mcap")
    assert result.messages == len(messages) and "the file ends inside the Attachment" in result.damage


def damaged_cosim_logs(sources, folder: Path) -> dict[str, Path]:
    """The short log of cosim with a flipped byte in a middle chunk (zstd), cut at 60 % (zstd), and
    with a chunk's declared size made huge (lz4)."""
    data = sources["cosim-zstd"].read_bytes()
    spans = chunks(sources["cosim-zstd"])
    flipped = bytearray(data)
    flipped[spans[len(spans) // 2][1] - 100] ^= 0x55
    lz4 = sources["cosim-lz4"].read_bytes()
    huge = bytearray(lz4)
    start = chunks(sources["cosim-lz4"])[2][0]
    huge[start + 9 + 16 : start + 9 + 24] = struct.pack("<Q", 2**62)
    found = {"flipped": flipped, "cut": data[: len(data) * 6 // 10], "huge": huge}
    for name, content in found.items():
        (folder / f"{name}.mcap").write_bytes(bytes(content))
    return {name: folder / f"{name}.mcap" for name in found}


def test_the_commands_on_damaged_logs_say_it_in_a_line(sources, tmp_path, capsys):
    commands = {
        "flipped": (["inspect"], ["export", "--to", "csv"], ["plot"]),
        "cut": (["inspect", "--json"], ["recover"], ["export", "--to", "candump"], ["plot"]),
        "huge": (["inspect"], ["recover"], ["export", "--to", "csv"]),
    }
    for name, path in damaged_cosim_logs(sources, tmp_path).items():
        for command in commands[name]:
            out = {"recover": "fixed.mcap", "export": f"out.{command[-1]}", "plot": "plots"}.get(command[0])
            out = out and f"{name}-{out}"
            assert main([command[0], str(path), *command[1:], *(["--out", str(tmp_path / out)] if out else [])]) == 0
            said = capsys.readouterr()
            text = said.err + (said.out if command[0] == "inspect" else "")
            assert "damaged" in text or "cut" in text or "ends" in text, (name, command, text)
