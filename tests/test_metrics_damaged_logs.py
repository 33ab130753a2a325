"""Metrics of damaged and foreign files: the hand-made log (tests/hand_log.py) cut or byte-flipped
in one of its many small chunks, randomly damaged, read by ``cosim inspect``; a log written by
another program; a cosim log with foreign messages on its topics."""

from __future__ import annotations

import json
import random
import subprocess
import sys

import pytest
from mcap.reader import make_reader

from cosim.analysis.metrics import compute_metrics
from cosim.errors import LogError
from cosim.log.reader import LogReader
from cosim.log.recorder import STATE
from cosim.log.writer import McapLog, object_schema
from tests.hand_log import N, write_hand_log
from tests.other_logs import write_other_log


@pytest.fixture(scope="module")
def hand(tmp_path_factory):
    """The metrics of the hand-made log as written (its usual chunks)."""
    path = tmp_path_factory.mktemp("hand") / "hand.mcap"
    write_hand_log(path)
    return compute_metrics(path)


def chunk_spans(path):
    with open(path, "rb") as stream:
        summary = make_reader(stream).get_summary()
    return [
        (c.chunk_start_offset, c.chunk_length)
        for c in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    ]


@pytest.fixture(scope="module")
def long_hand_log(tmp_path_factory):
    """The hand-made log with small chunks, so that damage hits one of many."""
    path = tmp_path_factory.mktemp("long") / "hand.mcap"
    original = McapLog.__init__

    def small_chunks(self, p, *, chunk_size=4096):
        original(self, p, chunk_size=chunk_size)

    McapLog.__init__ = small_chunks
    try:
        write_hand_log(path)
    finally:
        McapLog.__init__ = original
    assert len(chunk_spans(path)) > 10
    return path


def test_a_log_cut_in_the_middle_of_a_chunk_gives_a_partial_result(long_hand_log, tmp_path):
    data = long_hand_log.read_bytes()
    start, length = chunk_spans(long_hand_log)[len(chunk_spans(long_hand_log)) // 2]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: start + length // 2])
    report = compute_metrics(cut)
    assert report["status"] == "incomplete" and 0 < report["ticks"] < N
    assert any("no summary section" in w for w in report["warnings"])
    assert any("damaged or cut after t =" in w for w in report["warnings"])
    assert any("cosim.result" in m for m in report["missing"])
    assert report["estimators"]["uniform"]["rms_pre_fault"] == pytest.approx(0.1)


def test_flipped_bytes_in_a_chunk_skip_that_chunk(long_hand_log, tmp_path, hand):
    data = bytearray(long_hand_log.read_bytes())
    start, length = chunk_spans(long_hand_log)[3]
    data[start + length // 2 : start + length // 2 + 8] = bytes(
        b ^ 0xFF for b in data[start + length // 2 : start + length // 2 + 8]
    )
    flipped = tmp_path / "flipped.mcap"
    flipped.write_bytes(bytes(data))
    report = compute_metrics(flipped)
    (warning,) = report["warnings"]
    assert warning.startswith("a damaged chunk was skipped")
    assert (
        report["ticks"] == N
        and report["estimators"]["uniform"]["final_error"] == hand["estimators"]["uniform"]["final_error"]
    )


def test_random_damage_never_raises_anything_but_a_log_error(long_hand_log, tmp_path):
    data = long_hand_log.read_bytes()
    rng = random.Random(3)
    damaged = tmp_path / "damaged.mcap"
    for trial in range(120):
        corrupt = bytearray(data)
        if trial % 4 == 0:
            corrupt = corrupt[: rng.randrange(len(corrupt))]
        else:
            for _ in range(rng.randrange(1, 20)):
                corrupt[rng.randrange(len(corrupt))] ^= 1 << rng.randrange(8)
        damaged.write_bytes(bytes(corrupt))
        try:
            report = compute_metrics(damaged)
        except LogError:
            continue
        json.dumps(report)
        assert isinstance(report["warnings"], list)


def test_the_cli_on_a_cut_log_prints_a_partial_report_without_traceback(long_hand_log, tmp_path):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(long_hand_log.read_bytes()[: len(long_hand_log.read_bytes()) // 3])
    result = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "inspect", str(cut)], check=False, capture_output=True, text=True
    )
    assert result.returncode == 0 and "Traceback" not in result.stderr
    assert "warning:" in result.stdout and "estimation error" in result.stdout and "bus" in result.stdout


def test_a_log_written_by_another_program_says_what_is_missing(tmp_path):
    messages = [
        (topic, i * 1_000_000_000, data)
        for i in range(5)
        for topic, data in (("/pose", b'{"x": 1}'), ("/truth/state", b"[1, 2]"))  # not a cosim truth message
    ]
    path = write_other_log(tmp_path / "other.mcap", messages)
    report = compute_metrics(path)
    assert report["channels"] == {"/pose": 5, "/truth/state": 5} and report["time_span_s"] == 4.0
    assert (
        report["scenario"] is None
        and report["estimators"] == {}
        and report["diagnosis"] == {}
        and report["bus"] is None
    )
    assert any("cosim.run metadata" in m for m in report["missing"])
    assert any("no cosim.run metadata" in w for w in report["warnings"])


def test_a_cosim_log_with_foreign_messages_on_its_topics_warns_and_goes_on(tmp_path):
    path = tmp_path / "odd.mcap"
    write_hand_log(path)
    with McapLog(tmp_path / "odd2.mcap") as log, LogReader(path) as reader:
        for name, values in reader.metadata().items():
            log.metadata(name, values)
        channels = {}
        for topic, t, msg in reader.messages():
            if topic not in channels:
                channels[topic] = log.channel(topic, object_schema("any", {}))
            if topic == STATE and t >= 5_000_000_000:
                msg = {"tock": 1}
            log.write(channels[topic], t, msg)
    report = compute_metrics(tmp_path / "odd2.mcap")
    (warning,) = report["warnings"]
    assert warning.startswith("/truth/state: a message at t = 5 s does not have the fields cosim writes")
    assert report["estimators"]["uniform"]["rms_pre_fault"] == pytest.approx(0.1)
