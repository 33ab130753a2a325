"""The command line: help, listings, the DBC, and inspecting files that are not cosim logs."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from contextlib import redirect_stdout

import pytest
from mcap.writer import Writer

from cosim.cli import main


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosim.cli", *args], capture_output=True, text=True)


def test_help_lists_the_commands_and_examples():
    result = run_cli("--help")
    assert result.returncode == 0
    for word in ("run", "scenarios", "inspect", "dbc", "examples:"):
        assert word in result.stdout
    run_help = run_cli("run", "--help").stdout
    assert "--seed N" in run_help and "--out FILE.mcap" in run_help


def test_scenarios_lists_the_default():
    result = run_cli("scenarios")
    assert result.returncode == 0 and "masses-bias (default)" in result.stdout


def test_dbc_to_stdout_is_a_database():
    result = run_cli("dbc")
    assert (
        result.returncode == 0 and "BO_ 128 SYNC: 5 runner" in result.stdout and "SENSOR_x1_minus_x2" in result.stdout
    )


def test_inspect_of_a_file_that_is_not_mcap(tmp_path):
    bogus = tmp_path / "notes.mcap"
    bogus.write_text("hello")
    result = run_cli("inspect", str(bogus))
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert result.stderr.startswith(f"error: {bogus}: not a readable MCAP file")
    missing = run_cli("inspect", str(tmp_path / "none.mcap"))
    assert missing.returncode == 1 and "no such file" in missing.stderr


def test_inspect_of_a_log_written_by_another_program(tmp_path):
    path = tmp_path / "other.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start()
        schema = writer.register_schema("x", "jsonschema", b'{"type":"object"}')
        channel = writer.register_channel("/pose", "json", schema)
        for i in range(5):
            writer.add_message(channel, i, b'{"x": 1}', i)
        writer.finish()
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(["inspect", str(path), "--json"]) == 0
    report = json.loads(out.getvalue())
    assert report["channels"] == {"/pose": 5} and report["scenario"] is None and report["estimators"] == {}
    assert any("no cosim.run metadata" in w for w in report["warnings"])


@pytest.mark.slow
def test_bad_output_paths_and_seeds_are_one_line_errors(tmp_path):
    result = run_cli("run", "--seed", "-1")
    assert result.returncode == 2 and "--seed: -1 is negative; seeds are >= 0" in result.stderr
    for args in (
        ("run", "-q", "--out", str(tmp_path)),
        ("dbc", "--out", str(tmp_path / "no" / "x.dbc")),
        ("inspect", str(tmp_path)),
    ):
        result = run_cli(*args)
        assert result.returncode == 1 and "Traceback" not in result.stderr, args
        assert result.stderr.strip().splitlines()[-1].startswith("error: "), args
