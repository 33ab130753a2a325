"""The logs open in MCAP viewers: two independent MCAP implementations read every message the
official Python reader reads (the layouts Foxglove opens them with are tested in tests/test_foxglove.py).

- pybag (PyPI ``pybag-sdk``, MIT, its own MCAP parser: no code shared with ``mcap``), in the test
  extra: always runs.
- @mcap/core, the TypeScript library Foxglove opens files with, run with Node.js (>= 18):
  ``tests/mcap_ts`` pins it (package-lock.json); the test installs it once with ``npm ci`` into
  ``~/.cache/cosim/mcap-ts-<lock hash>`` (``COSIM_MCAP_TS_DIR`` overrides the place). It is skipped,
  saying so, only when ``node`` and ``npm`` are not installed.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import struct
import subprocess
import zlib
from collections import defaultdict
from pathlib import Path

import pytest
from mcap.reader import make_reader

import cosim
from cosim.run import Run
from cosim.scenario import LoadedScenario, load
from tests.conftest import ROOT

TS_DIR = ROOT / "tests" / "mcap_ts"


def run_short(name: str, duration: float, out: Path) -> Path:
    scenario = load(name).scenario.model_copy(update={"duration": duration})
    Run(LoadedScenario(scenario, f"{name} ({duration:g} s)", ""), out, interface="virtual").execute()
    return out


@pytest.fixture(scope="module", params=["masses-bias", "masses-faults-fd", "uio-fault-detection"])
def log(request, tmp_path_factory) -> Path:
    return run_short(request.param, 6.0, tmp_path_factory.mktemp("readers") / f"{request.param}.mcap")


def digest(messages: list[tuple[int, int, bytes]]) -> str:
    """sha256 over (log time u64, sequence u32, length u32, data) of a topic's messages in sequence
    order: the same definition as tests/mcap_ts/read_mcap.mjs."""
    hash = hashlib.sha256()
    for sequence, log_time, data in sorted(messages):
        hash.update(struct.pack("<QII", log_time, sequence, len(data)) + data)
    return hash.hexdigest()


def describe(channels, schemas, messages, metadata, attachments, message_count) -> dict:
    """What a reader saw, in the shape read_mcap.mjs prints."""
    topics = {}
    for channel_id, channel in channels.items():
        schema = schemas.get(channel.schema_id)
        topics[channel.topic] = {
            "messageEncoding": channel.message_encoding,
            "schemaName": schema.name if schema else None,
            "schemaEncoding": schema.encoding if schema else None,
            "schema": json.loads(schema.data) if schema else None,
            "count": len(messages[channel_id]),
            "digest": digest(messages[channel_id]),
        }
    return {
        "messageCount": message_count,
        "topics": topics,
        "metadata": metadata,
        "attachments": {
            a.name: {"mediaType": a.media_type, "sha256": hashlib.sha256(a.data).hexdigest()} for a in attachments
        },
    }


def read_with_mcap(path: Path) -> dict:
    """The official Python reader (what cosim itself uses)."""
    with open(path, "rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        messages = defaultdict(list)
        for _, channel, message in reader.iter_messages():
            messages[channel.id].append((message.sequence, message.log_time, bytes(message.data)))
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        attachments = list(reader.iter_attachments())
        return describe(
            summary.channels, summary.schemas, messages, metadata, attachments, summary.statistics.message_count
        )


def read_with_pybag(path: Path) -> dict:
    """pybag, CRCs checked (chunks and summary), except the attachments': pybag 0.13 computes an
    attachment's CRC over its data only, where the MCAP spec covers every field before the CRC
    (log time, create time, name, media type, data); attachment CRCs are checked by
    attachment_crcs_follow_the_spec and by @mcap/core."""
    from pybag.mcap.record_reader import McapChunkedReader

    with McapChunkedReader.from_file(path, enable_crc_check=True, enable_summary_reconstruction="never") as reader:
        messages = defaultdict(list)
        for message in reader.get_messages(in_log_time_order=False):
            messages[message.channel_id].append((message.sequence, message.log_time, bytes(message.data)))
        metadata = {m.name: dict(m.metadata) for m in reader.get_metadata()}
        channels, schemas, count = reader.get_channels(), reader.get_schemas(), reader.get_statistics().message_count
    with McapChunkedReader.from_file(path, enable_crc_check=False, enable_summary_reconstruction="never") as reader:
        attachments = reader.get_attachments()
    return describe(channels, schemas, messages, metadata, attachments, count)


def attachment_crcs_follow_the_spec(path: Path) -> int:
    """Checks each attachment record's CRC-32 over the fields before it (MCAP spec, Attachment
    record); returns how many were checked."""
    data = path.read_bytes()
    with open(path, "rb") as stream:
        indexes = make_reader(stream).get_summary().attachment_indexes
    for index in indexes:
        body = data[index.offset + 9 : index.offset + index.length]  # after opcode (1) and record length (8)
        assert zlib.crc32(body[:-4]) == struct.unpack("<I", body[-4:])[0], index.name
    return len(indexes)


def test_pybag_reads_what_the_official_reader_reads(log):
    official = read_with_mcap(log)
    assert official["messageCount"] == sum(t["count"] for t in official["topics"].values()) > 10_000
    assert read_with_pybag(log) == official
    assert (
        attachment_crcs_follow_the_spec(log) == len(official["attachments"]) and "cosim.dbc" in official["attachments"]
    )


def typescript_reader() -> Path:
    """tests/mcap_ts with its pinned dependencies installed (npm ci), in a cache directory."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip("Node.js (node and npm, >= 18) is not installed: the @mcap/core reader cannot run")
    lock = (TS_DIR / "package-lock.json").read_bytes()
    folder = Path(
        os.environ.get("COSIM_MCAP_TS_DIR")
        or Path.home() / ".cache" / "cosim" / f"mcap-ts-{hashlib.sha256(lock).hexdigest()[:12]}"
    )
    folder.mkdir(parents=True, exist_ok=True)
    for name in ("package.json", "package-lock.json", "read_mcap.mjs"):
        shutil.copyfile(TS_DIR / name, folder / name)
    if not (folder / "node_modules" / "@mcap" / "core").is_dir():
        result = subprocess.run(
            [npm, "ci", "--no-audit", "--no-fund", "--ignore-scripts"],
            cwd=folder,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert result.returncode == 0, f"npm ci in {folder} failed:\n{result.stderr}"
    return folder


@pytest.mark.slow
def test_the_typescript_reader_of_foxglove_reads_what_the_official_reader_reads(log):
    folder = typescript_reader()
    result = subprocess.run(
        ["node", str(folder / "read_mcap.mjs"), str(log)], capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr
    seen = json.loads(result.stdout)
    assert (
        seen.pop("library") == f"cosim/{cosim.__version__}"
        and seen.pop("compression") == ["zstd"]
        and seen.pop("chunks") > 1
    )
    seen.pop("profile")
    assert seen == read_with_mcap(log)


def test_the_log_writer_writes_the_bytes_of_the_official_writer(tmp_path, monkeypatch):
    """McapLog's short path for messages (cosim.log.writer._Writer) changes no byte of the file."""
    from mcap.writer import Writer

    from cosim.log import writer as writer_module

    def write(path: Path) -> bytes:
        with writer_module.McapLog(path, chunk_size=4096) as log:  # many chunks
            assert getattr(log._writer, "_fast", True)  # ours takes the short path (the official has none)
            a = log.channel("/a", {"title": "a", "type": "object"})
            b = log.channel("/b", {"title": "b", "type": "object"})
            log.metadata("m", {"k": "v"})
            for k in range(3000):
                log.write(a, 10 * k, {"tick": k, "x": k / 7})
                if k % 3 == 0:
                    log.write(b, 10 * k - 5 if k else 0, {"tick": k, "y": [k, -k]})  # out of order in time
                if k == 1500:
                    log.flush()
                    log.attach("file.txt", "text/plain", b"hello", 10 * k)
        return path.read_bytes()

    ours = write(tmp_path / "ours.mcap")
    monkeypatch.setattr(writer_module, "_Writer", Writer)
    official = write(tmp_path / "official.mcap")
    assert ours == official


def test_damaged_message_indexes_are_reported_and_the_messages_still_read(tmp_path):
    """A chunk's message indexes carry no CRC: the reader checks each entry against the message it
    points at, warns where one does not (or the count differs), and reads the chunk all the same."""
    from mcap.reader import make_reader as official

    from cosim.log.reader import LogReader
    from cosim.log.writer import McapLog

    path = tmp_path / "log.mcap"
    with McapLog(path, chunk_size=4096) as log:
        channel = log.channel("/a", {"title": "a", "type": "object"})
        for k in range(2000):
            log.write(channel, 10 * k, {"tick": k})
    with path.open("rb") as stream:
        summary = official(stream).get_summary()
    assert summary is not None
    first = min(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    entries_at = first.message_index_offsets[channel] + 1 + 8 + 2 + 4  # opcode, length, channel id, byte length

    def read(data: bytes) -> tuple[int, list[str]]:
        path.write_bytes(data)
        with LogReader(path) as reader:
            return sum(1 for _ in reader.messages()), reader.warnings

    intact = path.read_bytes()
    assert read(intact) == (2000, [])
    moved = bytearray(intact)
    moved[entries_at + 8 : entries_at + 16] = struct.pack("<Q", 3)  # the first entry's offset
    count, warnings = read(bytes(moved))
    assert count == 2000 and len(warnings) == 1 and "1 of its" in warnings[0] and "do not point at" in warnings[0]
    cut = bytearray(intact)
    cut[entries_at - 4 : entries_at] = struct.pack("<I", 16)  # the array now lists one entry
    count, warnings = read(bytes(cut))
    assert count == 2000 and len(warnings) == 1 and "message indexes" in warnings[0]
