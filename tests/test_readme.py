"""What the README's Python example relies on (tests/test_docs.py runs the example itself and checks what it prints)."""

from __future__ import annotations


def test_a_fault_after_the_runs_end_is_warned_about():
    from cosim import api
    from cosim.scenario.load import timing_warnings

    late = api.load_scenario("masses-bias", {"duration": 5.0}).scenario  # the bias starts at 5 s
    assert timing_warnings(late) == [
        "faults[0] (bias) starts at 5 s, after the run's last tick (t = 4.99 s): it never happens; "
        "start it earlier or lengthen the run (duration = 5)"
    ]
    assert timing_warnings(api.load_scenario("masses-bias", {"duration": 5.01}).scenario) == []
