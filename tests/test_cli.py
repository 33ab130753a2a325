"""The command line: help, listings, the DBC, and inspecting files that are not cosim logs."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from contextlib import redirect_stdout
from pathlib import Path

import pytest

from cosim.cli import main
from tests.other_logs import write_other_log


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
        result.returncode == 0 and "BO_ 128 SYNC: 8 runner" in result.stdout and "SENSOR_x1_minus_x2" in result.stdout
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
    path = write_other_log(tmp_path / "other.mcap", [("/pose", i, b'{"x": 1}') for i in range(5)])
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


# -- no surprises ---------------------------------------------------------------------------------


def test_scenarios_json_lists_every_builtin_scenario(capsys):
    from cosim.scenario import builtin_names

    assert main(["scenarios", "--json"]) == 0
    listing = json.loads(capsys.readouterr().out)
    assert [s["name"] for s in listing] == builtin_names()
    default = next(s for s in listing if s["default"])
    assert default["name"] == "masses-bias" and default["estimators"] == ["uniform", "kalman"]
    assert all(s["error"] is None and s["duration_s"] > 0 and s["bus"] in ("CAN FD", "classic CAN") for s in listing)


def test_a_misspelt_scenario_gets_the_near_names(capsys):
    assert main(["run", "masses-bais"]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert err.startswith("error: no built-in scenario 'masses-bais': did you mean masses-bias")
    assert err.strip().endswith("? ('cosim scenarios' lists the built-in ones)")
    assert main(["dbc", "vessel-falt-T1"]) == 1
    assert "did you mean vessel-fault-T1" in capsys.readouterr().err


def test_options_that_would_do_nothing_are_errors(capsys):
    assert main(["run", "--speed", "2", "--interface", "virtual"]) == 1
    err = capsys.readouterr().err
    assert "--speed 2: only in realtime mode (add --mode realtime); masses-bias runs in lockstep" in err
    assert main(["run", "--interface", "virtual", "--port", "4000"]) == 1
    assert "--port: only for the udp_multicast interface, not virtual" in capsys.readouterr().err


def test_run_json_prints_the_summary(tmp_path, capsys):
    out = tmp_path / "r.mcap"
    assert main(["run", "--interface", "virtual", "--set", "duration=0.5", "-q", "--json", "--out", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["path"] == str(out) and summary["status"] == "completed" and summary["ticks"] == 50
    assert summary["frames"] > 500 and summary["lost"] == 0 and summary["realtime_factor"] > 0
    assert set(summary) >= {"path", "status", "ticks", "frames", "lost", "realtime_factor", "wall_time_s", "error"}


def test_a_run_whose_bus_cannot_open_does_not_claim_a_log(tmp_path, capsys):
    out = tmp_path / "never.mcap"
    code = main(["run", "--interface", "socketcan", "--channel", "cosimnone0", "-q", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1 and "error:" in err and "Traceback" not in err
    if not out.exists():
        assert f"no log was written ({out} does not exist)" in err and "the log up to that point" not in err


def test_a_missing_extra_is_one_line_naming_it(tmp_path, capsys, monkeypatch):
    from cosim.extras import MissingExtra, missing_extra

    out = tmp_path / "r.mcap"
    assert main(["run", "--interface", "virtual", "--set", "duration=0.2", "-q", "--out", str(out)]) == 0
    capsys.readouterr()
    for module in ("pyarrow", "pyarrow.parquet"):  # as if the export extra were not installed (even if imported)
        monkeypatch.setitem(sys.modules, module, None)
    assert main(["export", str(out), "--to", "parquet"]) == 1
    assert capsys.readouterr().err.strip() == (
        "error: cosim export --to parquet needs the 'export' extra (pyarrow is not installed): "
        "pip install 'cosim[export]'"
    )
    campaign = tmp_path / "campaign"
    assert main(["campaign", "masses-bias-sweep", "--out", str(campaign), "--engine", "inline", "-q"]) == 1
    assert capsys.readouterr().err.strip() == (
        "error: cosim campaign needs the 'campaign' extra (pyarrow is not installed): pip install 'cosim[campaign]'"
    )
    assert not (campaign / "runs").exists()  # refused before any run
    monkeypatch.setitem(sys.modules, "distributed", None)
    assert main(["campaign", "masses-bias-sweep", "--out", str(campaign), "--engine", "dask", "-q"]) == 1
    assert "needs the 'campaign' extra" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    assert main(["plot", str(out)]) == 1
    assert "cosim plot needs the 'plot' extra (matplotlib is not installed)" in capsys.readouterr().err
    error = missing_extra(
        ModuleNotFoundError("No module named 'cvxpy'", name="cvxpy"), "cosim run three-tank-reconciliation"
    )
    assert isinstance(error, MissingExtra) and "needs the 'lmi' extra" in str(error)
    assert missing_extra(ModuleNotFoundError("x", name="somethingelse"), "cosim run") is None


def test_a_command_names_every_extra_it_lacks_at_once(tmp_path, capsys, monkeypatch):
    """Not one extra per attempt: the engine's, the figures', an FMU plant's and an estimator design's
    in one line, before anything runs."""
    for module in ("pyarrow", "pyarrow.parquet", "matplotlib", "cvxpy", "clarabel", "fmpy"):
        monkeypatch.setitem(sys.modules, module, None)
    assert main(["leaderboard", str(tmp_path / "results.parquet"), "--html", str(tmp_path / "b.html")]) == 1
    assert capsys.readouterr().err.strip() == (
        "error: cosim leaderboard --html needs the 'campaign' and 'plot' extras (pyarrow, matplotlib are not "
        "installed): pip install 'cosim[campaign,plot]'"
    )
    out = tmp_path / "campaign"
    assert main(["campaign", "three-tank-gains", "--out", str(out), "--engine", "inline", "-q"]) == 1
    assert " ".join(capsys.readouterr().err.split()) == (
        "error: cosim campaign (three-tank-gains (lpv-uio-sr, lft-uio-sr)) needs the 'campaign' and 'lmi' extras "
        "(pyarrow, cvxpy, clarabel are not installed): pip install 'cosim[campaign,lmi]'"
    )
    assert not out.exists()
    monkeypatch.setitem(sys.modules, "foxglove", None)
    run = ["run", "three-tank-reconciliation", "--foxglove", "0", "-q", "--out", str(tmp_path / "r.mcap")]
    assert main(run) == 1
    assert " ".join(capsys.readouterr().err.split()) == (
        "error: cosim run (three-tank-reconciliation (lpv-uio-sr, lft-uio-sr)) needs the 'live' and 'lmi' extras "
        "(foxglove-sdk, cvxpy, clarabel are not installed): pip install 'cosim[live,lmi]'"
    )
    assert not (tmp_path / "r.mcap").exists()


def test_monitor_with_two_runs_names_the_option_that_chooses(tmp_path, capsys, monkeypatch):
    from cosim.bus.registry import Registration

    monkeypatch.setenv("COSIM_RUNTIME_DIR", str(tmp_path))
    info = {"scenario": "masses-bias", "bus": {"interface": "virtual", "channel": "x"}}
    with Registration("aaaa11112222", info), Registration("bbbb33334444", info):
        assert main(["monitor"]) == 1
    err = capsys.readouterr().err
    assert "2 co-simulations are running" in err and "choose one with --run ID (e.g. cosim monitor --run" in err


def test_default_log_names_never_collide_and_an_existing_log_needs_force(tmp_path, monkeypatch, capsys):
    from cosim.cli import common

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(common, "stamp", lambda: "20261126-120000")  # two runs within one second
    quick = ["run", "--interface", "virtual", "--set", "duration=0.1", "-q"]
    assert main(quick) == 0 and main(quick) == 0
    first, second = capsys.readouterr().out.split()
    assert first != second and Path(first).exists() and Path(second).exists()
    assert Path(second).stem == Path(first).stem + "-2"
    size = Path(first).stat().st_size
    assert main([*quick, "--out", first]) == 1
    assert f"{first} exists: choose another file, or pass --force to replace it" in capsys.readouterr().err
    assert Path(first).stat().st_size == size
    assert main([*quick, "--out", first, "--force"]) == 0


def test_quiet_prints_nothing_but_the_path(tmp_path, capsys):
    out = tmp_path / "q.mcap"
    quick = ["run", "--interface", "virtual", "--set", "duration=0.1", "--set", "faults[0].start=0.05", "-q"]
    assert main([*quick, "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out == f"{out}\n"
    assert (
        main(["run", "--interface", "virtual", "--set", "duration=0.1", "-q", "--out", str(tmp_path / "w.mcap")]) == 0
    )
    assert capsys.readouterr().err.startswith("warning: faults[0] (bias) starts at 5 s")  # warnings still say


def test_a_virtual_bus_is_not_offered_to_other_programs(tmp_path, capsys):
    assert main(["run", "--interface", "virtual", "--set", "duration=0.1", "--out", str(tmp_path / "v.mcap")]) == 0
    err = capsys.readouterr().err
    assert "no other program can join it" in err and "can.Bus(" not in err
    assert err.count("\n") <= 5  # header, bus, progress, done


def test_latest_is_the_newest_log_in_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["inspect", "latest"]) == 1
    assert "no logs in runs/" in capsys.readouterr().err
    assert main(["run", "--interface", "virtual", "--set", "duration=0.2", "-q"]) == 0
    newest = capsys.readouterr().out.strip()
    assert main(["inspect", "--json"]) == 0 and main(["inspect", "latest", "--json"]) == 0
    first, second = capsys.readouterr().out.split("\n}\n", 1)
    assert json.loads(first + "}")["file"] == json.loads(second)["file"] == newest


def test_kinds_lists_every_group_with_its_origin(capsys):
    assert main(["kinds", "--json"]) == 0
    listing = json.loads(capsys.readouterr().out)
    assert set(listing) == {"cosim.estimators", "cosim.controllers", "cosim.faults", "cosim.plants"}
    kalman = next(e for e in listing["cosim.estimators"] if e["name"] == "kalman")
    assert kalman == {"name": "kalman", "source": "built-in", "target": "estimators.kalman:KalmanFilter"}
    assert {e["name"] for e in listing["cosim.plants"]} >= {"masses", "three_tank", "vessel"}
    assert main(["kinds"]) == 0
    assert "observers.py:MyObserver" in capsys.readouterr().out


def test_inspect_says_the_units_of_its_tables(tmp_path, capsys):
    out = tmp_path / "u.mcap"
    assert main(["run", "--interface", "virtual", "--set", "duration=6", "-q", "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["inspect", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["error_unit"] == "mixes m, m/s"  # positions and velocities
    assert main(["inspect", str(out)]) == 0
    text = capsys.readouterr().out
    assert "estimation error |x - x̂| (mixes m, m/s)" in text
    assert "onset [s]" in text and "recovery time after onset [s]" in text  # not read as rich markup
