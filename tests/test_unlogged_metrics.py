"""A run that writes no log (``cosim.api.run(scenario, None)``, a campaign run whose log is not kept)
is scored as it goes; its metrics are, field for field, those ``cosim inspect --json`` reads from
the log of the same run. Checked on every built-in scenario, each shortened to just past its first
fault (the same run twice: same seed, and the run secret fixed, so that the control frames' MACs,
and with them their stuff bits, repeat too)."""

from __future__ import annotations

import json

import pytest

from cosim import api, scenario
from cosim.analysis.metrics import compute_metrics
from cosim.bus.keys import SECRET_ENV
from cosim.cli import main
from cosim.scenario import apply

#: Simulated seconds each built-in scenario is cut to: past its first faults, and short.
DURATIONS = {
    "cdc2016-ex1": 64.0,
    "cdc2016-ex2": 88.0,
    "masses-bias": 8.0,
    "masses-bus-ideal": 8.0,
    "masses-bus-overload": 12.0,
    "masses-faults-fd": 12.0,
    "masses-spoofing": 14.0,
    "tac2024-s1-constant": 5.0,
    "tac2024-s1-timevarying": 5.0,
    "tac2024-s2-p4": 5.0,
    "three-tank-reconciliation": 420.0,
    "uio-fault-detection": 32.0,
    "vessel-nominal": 10.0,
    "vessel-reconfiguration": 26.0,
}
VESSEL_FAULT = 24.0  # the vessel-fault-* scenarios: their thrusters fail at 20 s


def duration(name: str) -> float:
    return DURATIONS.get(name, VESSEL_FAULT if name.startswith("vessel-fault-") else 0.0)


def test_every_builtin_scenario_has_a_duration():
    assert all(duration(name) for name in scenario.builtin_names())


@pytest.fixture
def fixed_secret(monkeypatch):
    monkeypatch.setenv(SECRET_ENV, "5e" * 32)


def without_file(metrics: dict) -> dict:
    assert metrics.pop("file") is not None
    return metrics


@pytest.mark.parametrize("name", scenario.builtin_names())
def test_unlogged_run_scores_what_its_log_reads(name, tmp_path, fixed_secret):
    loaded = apply(scenario.load(name), [("duration", duration(name))])
    unlogged = api.run(loaded, None, seed=1, in_process=True)
    assert unlogged.path is None and unlogged.metrics is not None
    logged = api.run(loaded, tmp_path / "run.mcap", seed=1, in_process=True)
    assert unlogged.status == logged.status == "completed", unlogged.error or logged.error
    live = unlogged.metrics.to_json()
    assert live["file"] == ""
    assert without_file(live) == without_file(compute_metrics(logged.path))


def test_inspect_json_is_what_an_unlogged_run_scores(tmp_path, fixed_secret, capsys):
    """The comparison above is with ``cosim inspect --json`` itself (``compute_metrics`` is its object)."""
    loaded = apply(scenario.load("masses-spoofing"), [("duration", 14.0), ("bus.intrusion_detector", True)])
    unlogged = api.run(loaded, None, seed=2, in_process=True)
    api.run(loaded, tmp_path / "run.mcap", seed=2, in_process=True)
    assert main(["inspect", str(tmp_path / "run.mcap"), "--json"]) in (0, None)
    printed = json.loads(capsys.readouterr().out)
    assert printed["bus"]["intrusion_detection"] is not None  # the detector's verdicts were scored
    assert without_file(printed) == without_file(unlogged.metrics.to_json())
