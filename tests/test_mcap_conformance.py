"""The MCAP conformance suite (foxglove/mcap, tests/conformance/data: 416 files, each with the JSON of
the records a reader must read from it; ../shared/mcap-conformance beside the checkout, README there)
read by our reader and by the official one.

Our reader returns what each JSON says (messages in file order with topic, schema, encodings, log
and publish time, sequence, data; attachments; metadata), on every file; the official reader
(``make_reader``) returns the same where it reads the file. It refuses (KeyError) those whose
summary does not repeat the Channel or Schema records, which ours reads by a scan; and where the
summary has no attachment or metadata index it returns none of them, which ours finds by a scan.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from cosim.log.reader import LogReader
from tests.conftest import ROOT

SUITE = ROOT.parent / "shared" / "mcap-conformance"
BASES = ("NoData", "OneAttachment", "OneMessage", "OneMetadata", "OneSchemalessMessage", "TenMessages")


def files(base: str) -> list[Path]:
    if not SUITE.is_dir():
        pytest.skip(f"{SUITE} is not there (CI has ../shared beside the checkout)")
    found = sorted((SUITE / base).glob("*.mcap"))
    assert found, f"no conformance files in {SUITE / base}"
    return found


def test_the_suite_is_whole():
    assert sum(len(files(base)) for base in BASES) == 416
    assert all(path.with_suffix(".json").is_file() for base in BASES for path in files(base))


def features(path: Path) -> set[str]:
    return set(json.loads(path.with_suffix(".json").read_text())["meta"]["variant"]["features"])


def expected(path: Path) -> dict:
    """What a reader must return, from the file's JSON (its records in file order)."""
    schemas: dict[str, dict] = {}
    channels: dict[str, dict] = {}
    found: dict[str, list] = {"messages": [], "attachments": [], "metadata": []}
    for record in json.loads(path.with_suffix(".json").read_text())["records"]:
        f = dict(record["fields"])
        kind = record["type"]
        if kind == "Schema":
            schemas.setdefault(f["id"], f)
        elif kind == "Channel":
            channels.setdefault(f["id"], f)
        elif kind == "Message":
            channel = channels[f["channel_id"]]
            schema = schemas.get(channel["schema_id"])
            found["messages"].append(
                (
                    channel["topic"],
                    channel["message_encoding"],
                    channel["metadata"],
                    schema and (schema["name"], schema["encoding"], bytes(int(b) for b in schema["data"])),
                    int(f["log_time"]),
                    int(f["publish_time"]),
                    int(f["sequence"]),
                    bytes(int(b) for b in f["data"]),
                )
            )
        elif kind == "Attachment":
            found["attachments"].append(
                (
                    f["name"],
                    f["media_type"],
                    int(f["log_time"]),
                    int(f["create_time"]),
                    bytes(int(b) for b in f["data"]),
                )
            )
        elif kind == "Metadata":
            found["metadata"].append((f["name"], f["metadata"]))
    return found


def message(schema, channel, record) -> tuple:
    return (
        channel.topic,
        channel.message_encoding,
        dict(channel.metadata),
        schema and (schema.name, schema.encoding, bytes(schema.data)),
        record.log_time,
        record.publish_time,
        record.sequence,
        bytes(record.data),
    )


def attachments(found) -> list[tuple]:
    return [(a.name, a.media_type, a.log_time, a.create_time, bytes(a.data)) for a in found]


def read_with_ours(path: Path) -> tuple[dict, list[str]]:
    with LogReader(path) as reader:
        return {
            "messages": [message(*m) for m in reader.raw_messages()],
            "attachments": attachments(reader.attachment_records()),
            "metadata": [(m.name, dict(m.metadata)) for m in reader.metadata_records()],
        }, reader.warnings


def read_with_official(path: Path) -> dict:
    with open(path, "rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        return {
            "messages": [message(*m) for m in reader.iter_messages(log_time_order=False)],
            "attachments": attachments(reader.iter_attachments()),
            "metadata": [(m.name, dict(m.metadata)) for m in reader.iter_metadata()],
        }


@pytest.mark.parametrize("base", BASES)
def test_our_reader_reads_what_each_file_holds(base):
    for path in files(base):
        ours, warnings = read_with_ours(path)
        assert ours == expected(path), path.name
        assert warnings == [], path.name


@pytest.mark.parametrize("base", BASES)
def test_the_official_reader_reads_the_same_where_it_reads_the_file(base):
    for path in files(base):
        ours, _ = read_with_ours(path)
        # it seeks by the chunk index, and takes channels and schemas from the summary alone
        listed = {"rch"} if base == "OneSchemalessMessage" else {"rch", "rsh"}
        refuses = "chx" in features(path) and not features(path) >= listed
        try:
            official = read_with_official(path)
        except KeyError:
            assert refuses, path.name
            assert {m[0] for m in ours["messages"]} == {"example"}, path.name  # ours scans for them
            continue
        assert not refuses, path.name
        assert official["messages"] == ours["messages"], path.name
        for kind, index in (("attachments", "ax"), ("metadata", "mdx")):
            if index in features(path) or "sum" not in features(path) and "st" not in features(path):
                assert official[kind] == ours[kind], path.name
            else:  # a summary without that index: the official reader returns none; ours scans
                holder = {"attachments": "OneAttachment", "metadata": "OneMetadata"}[kind]
                assert official[kind] == [] and len(ours[kind]) == (base == holder), path.name


def test_inspect_says_what_mcap_info_says_of_any_file(tmp_path):
    import subprocess
    import sys

    from cosim.analysis.summary import summarize

    channel = {
        "id": 1,
        "topic": "example",
        "message_encoding": "a",
        "schema": "Example",
        "schema_encoding": "c",
        "messages": 10,
        "metadata": {"foo": "bar"},
    }
    for name in ("TenMessages-ch-chx-mx-rch-rsh-st-sum", "TenMessages-ch-chx-mx-st-sum", "TenMessages-pad"):
        info = summarize(SUITE / "TenMessages" / f"{name}.mcap")["mcap"]  # with statistics; without rch; no summary
        assert info["channels"] == [channel] and (info["messages"], info["start_ns"], info["end_ns"]) == (10, 0, 9)
        assert info["attachments"] == info["metadata"] == [] and (info["library"], info["profile"]) == ("", "")
    assert summarize(SUITE / "TenMessages" / "TenMessages-ch-chx-mx-st-sum.mcap")["mcap"]["chunks"] == {
        "none": {"chunks": 1, "compressed": 421, "uncompressed": 421}
    }
    info = summarize(SUITE / "OneAttachment" / "OneAttachment-ax-pad-st-sum.mcap")["mcap"]
    assert info["attachments"] == [
        {"name": "myFile", "media_type": "application/octet-stream", "bytes": 3, "log_time_ns": 2, "create_time_ns": 1}
    ]
    info = summarize(SUITE / "OneMetadata" / "OneMetadata-mdx-pad-st-sum.mcap")["mcap"]
    assert info["metadata"] == [{"name": "myMetadata", "metadata": {"foo": "bar"}}] and info["channels"] == []
    path = SUITE / "TenMessages" / "TenMessages-ch-chx-mx-st-sum.mcap"
    result = subprocess.run([sys.executable, "-m", "cosim.cli", "inspect", str(path)], capture_output=True, text=True)
    assert result.returncode == 0 and result.stderr == ""
    lines = [line.split() for line in result.stdout.splitlines()]
    assert ["messages:", "10"] in lines and ["duration:", "9ns"] in lines and ["end:", "0.000000009"] in lines
    assert ["1", "example", "10", "1.111e+09", "Hz", "Example", "[c]", "a"] in lines
    assert "estimation error" not in result.stdout  # not a log of cosim: no metrics


def test_a_padded_attachment_is_read_by_its_fields():
    """The format lets records grow at their end: the attachment CRC is its last field, not the
    record's last 4 bytes (the old reader dropped this one as damaged)."""
    with LogReader(SUITE / "OneAttachment" / "OneAttachment-ax-pad-st-sum.mcap") as reader:
        assert reader.attachments() == {"myFile": b"\x01\x02\x03"} and reader.warnings == []


def test_payloads_that_are_not_json_are_not_damage(tmp_path):
    with LogReader(SUITE / "TenMessages" / "TenMessages-ch-chx-mx-rch-rsh-st-sum.mcap") as reader:
        assert list(reader.messages()) == []
        assert reader.warnings == [
            "messages that are not JSON were not decoded (cosim reads JSON messages): example (a): 10"
        ]
    from tests.other_logs import write_other_log

    path = write_other_log(
        tmp_path / "bad.mcap", [("/pose", k * 10**9, b'{"x": 1}' if k != 2 else b"\x01\x02") for k in range(4)]
    )
    with LogReader(path) as reader:
        assert [t for _, t, _ in reader.messages()] == [0, 10**9, 3 * 10**9]
        (warning,) = reader.warnings
        assert warning.startswith("/pose: the message at t = 2 s is not valid JSON") and warning.endswith("skipped")
