"""Damaged and foreign files give one line naming the file and the problem, never a traceback."""

from __future__ import annotations

import shutil
import subprocess
import sys

from cosim.log.metadata import DBC_ATTACHMENT
from cosim.log.reader import LogReader


def cosim(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosim.cli", *args], capture_output=True, text=True, timeout=300)


def flip_a_byte_of_the_dbc(source, target):
    """A copy of the log with one byte of its DBC attachment changed (its record's CRC left as it was)."""
    shutil.copy(source, target)
    data = bytearray(target.read_bytes())
    at = data.index(b"BO_ ") + 1
    data[at] ^= 0xFF
    target.write_bytes(bytes(data))


def test_a_flipped_byte_in_the_dbc_attachment_is_one_line_in_replay_and_layout(default_run, tmp_path):
    damaged = tmp_path / "damaged.mcap"
    flip_a_byte_of_the_dbc(default_run.path, damaged)
    with LogReader(damaged) as reader:
        assert DBC_ATTACHMENT not in reader.attachments()
        assert any("'cosim.dbc' is damaged" in warning for warning in reader.warnings)
    with LogReader(default_run.path) as reader:
        assert DBC_ATTACHMENT in reader.attachments() and not reader.warnings
    for command in (
        ["replay", str(damaged), "--estimator", "kalman", "--out", str(tmp_path / "r.mcap")],
        ["layout", str(damaged), "--out", str(tmp_path / "layout.json")],
    ):
        result = cosim(*command)
        assert result.returncode != 0
        lines = result.stderr.strip().splitlines()
        assert lines[-1] == (
            f"error: {damaged}: cannot read the run's CAN database: the attachment 'cosim.dbc' is damaged "
            "(its bytes do not match their CRC)"
        ), result.stderr
        assert "Traceback" not in result.stderr
