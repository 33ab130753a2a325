"""A run that writes no log (``cosim.api.run(scenario, None)``, a campaign run whose log is not kept)
is scored as it goes; its metrics are, field for field, those ``cosim inspect --json`` reads from
the log of the same run. Checked on every built-in scenario, each cut short past its first faults
(the same run twice: same seed, and the run secret fixed, so that the control frames' MACs, and
with them their stuff bits, repeat too)."""

from __future__ import annotations

import json

import pytest

from cosim import api, scenario
from cosim.analysis.metrics import compute_metrics
from cosim.bus.keys import SECRET_ENV
from cosim.cli import main
from cosim.scenario import apply

#: Settings that cut each built-in scenario short, past its first faults.
SHORT: dict[str, list[tuple[str, object]]] = {
    "cdc2016-ex1": [("duration", 8.0), ("faults[0].start", 4.0)],
    "cdc2016-ex2": [("duration", 8.0), ("faults[0].start", 4.0)],
    "masses-bias": [("duration", 8.0)],
    "masses-bus-ideal": [("duration", 8.0)],
    "masses-bus-overload": [("duration", 12.0)],
    "masses-pid-can": [("duration", 8.0)],
    "masses-faults-fd": [("duration", 12.0)],
    "masses-spoofing": [("duration", 14.0)],
    "tac2024-s1-constant": [("duration", 5.0)],
    "tac2024-s1-timevarying": [("duration", 5.0)],
    "tac2024-s2-p4": [("duration", 5.0)],
    "three-tank-reconciliation": [  # a gain fault's hypotheses cost the gain tests much: a few ticks of it
        ("duration", 34.0),
        ("faults[0].start", 30.0),
        ("faults[1].start", 60.0),  # after the end: never happens (the run warns)
        ("faults[2].start", 10.0),
    ],
    "uio-fault-detection": [
        ("duration", 8.0),
        ("faults[0].start", 2.0),
        ("faults[0].end", 4.0),
        ("faults[1].start", 6.0),
    ],
    "vessel-nominal": [("duration", 10.0)],
    "vessel-reconfiguration": [("duration", 26.0)],
}
VESSEL_FAULT = [("duration", 24.0)]  # the vessel-fault-* scenarios: their thrusters fail at 20 s


def short(name: str) -> list[tuple[str, object]]:
    return SHORT.get(name, VESSEL_FAULT if name.startswith("vessel-fault-") else [])


def test_every_builtin_scenario_is_cut_short():
    assert all(short(name) for name in scenario.builtin_names())


@pytest.fixture
def fixed_secret(monkeypatch):
    monkeypatch.setenv(SECRET_ENV, "5e" * 32)


def without_file(metrics: dict) -> dict:
    """The metrics but what describes the file itself: its path and (``cosim inspect --json``) its MCAP records."""
    assert metrics.pop("file") is not None
    metrics.pop("mcap", None)
    return metrics


#: Scenarios whose plan alone takes many seconds (the reconciliators' windows): in the slow set.
SLOW = ("three-tank-reconciliation",)


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in scenario.builtin_names()]
)
def test_unlogged_run_scores_what_its_log_reads(name, tmp_path, fixed_secret):
    loaded = apply(scenario.load(name), short(name))
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
