"""How a batch takes its runs' ticks on an arbitrated wire: a node's tick taken whole, the ticks
scored whole or by parts, the steady ticks (``cosim.campaign.run_wire``, ``steady_wire``), each way
held against the runs alone."""

from __future__ import annotations

from collections import Counter, defaultdict

import pytest

from tests.test_batch_wire import (
    BUS_FAULTS,
    SEEDS,
    TAXONOMY,
    assert_batched_as_alone,
    closed_loop,
    open_loop,
    taps,  # noqa: F401 (a fixture)
)


@pytest.mark.parametrize(
    "loaded",
    [closed_loop(TAXONOMY["injection"]), open_loop(BUS_FAULTS["loss_x1"], True)],
    ids=["closed loop, spoofed", "open loop, frames lost"],
)
def test_a_nodes_tick_taken_whole_on_arrays_where_its_frames_are_the_runners_as_built_is_what_it_takes_alone(
    loaded,
    taps,  # noqa: F811 (the fixture)
    monkeypatch,
):
    """Where a tick's frames went on the channel as the runner built them and a node is between
    ticks, the batch hands it the tick's values on arrays (``RunWire.intake``); elsewhere (the
    attack's or the fault's window, the first tick) it takes its frames one by one: both ways,
    what each node takes in every tick is what it takes alone. Its answers and the runner's frames
    are encoded on arrays (``Codec.encode_rows``)."""
    from cosim.campaign.run_wire import RunWire

    intake, ways = RunWire.intake, defaultdict(lambda: [0, 0])

    def counted(self, name, k):
        tick = intake(self, name, k)
        ways[name][tick is None] += 1
        return tick

    encoded, published = RunWire.publish_encoded, Counter()

    def publishing(self, name, tick, frames):
        published[name] += 1
        return encoded(self, name, tick, frames)

    from cosim.campaign.batch_wire import WireBatch
    from cosim.campaign.steady_wire import SteadyWires

    runner, built = WireBatch._runner_frames, [0]

    def building(self, k, values, on, rows):
        found = runner(self, k, values, on, rows)
        built[0] += len(found)
        return found

    steady, answer, steady_ticks = SteadyWires.send, SteadyWires.answer, [0]
    materialize, materialized = SteadyWires.materialize, [0]

    def materializing(self, *args):
        materialized[0] += 1
        return materialize(self, *args)

    def sending(self, *args):
        found = steady(self, *args)
        steady_ticks[0] += int(found.sum())
        return found

    def answering(self, name, k, rows, names, values):
        published[name] += len(rows)
        return answer(self, name, k, rows, names, values)

    monkeypatch.setattr(RunWire, "intake", counted)
    monkeypatch.setattr(RunWire, "publish_encoded", publishing)
    monkeypatch.setattr(WireBatch, "_runner_frames", building)
    monkeypatch.setattr(SteadyWires, "send", sending)
    monkeypatch.setattr(SteadyWires, "answer", answering)
    monkeypatch.setattr(SteadyWires, "materialize", materializing)
    assert_batched_as_alone(loaded, taps)
    ticks = len(SEEDS) * loaded.scenario.ticks
    assert built[0] + steady_ticks[0] == ticks  # the runner's frames, on arrays (a steady tick's: bytes only)
    assert steady_ticks[0] > ticks // 4, steady_ticks  # outside the attack's or the fault's window
    nodes = [e.name for e in loaded.scenario.estimators] + (["controller"] if loaded.scenario.controller else [])
    assert sorted(ways) == sorted(nodes)
    for name, (whole, one_by_one) in ways.items():
        assert whole >= len(SEEDS) and one_by_one >= len(SEEDS), (name, whole, one_by_one)  # tick 0 at least
        assert whole + one_by_one + steady_ticks[0] == ticks, name  # each node's tick taken one of three ways
        assert published[name] == ticks + materialized[0], name  # on arrays (and again where brought back)


# a sensor fault from after the flood (0.9 s) until tick 111, the first tick scored whole again when
# the scorer scores a tick left incomplete 20 ticks on: the active faults the scores had last
# (the bias) are not those it had when it last scored a tick whole (none), which are those of tick 111
_UNTIL_BACK = {"name": "bias", "kind": "bias", "value": [0.0, 0.01, 0.0], "start": 0.95, "end": 1.11}


@pytest.mark.parametrize(
    ("loaded", "window", "whole"),
    [
        (closed_loop(TAXONOMY["injection"]), None, 0.95),
        (closed_loop(TAXONOMY["flooding"]), None, 0.2),
        (closed_loop(TAXONOMY["flooding"]), 20, 0.3),
        (closed_loop([*TAXONOMY["flooding"], _UNTIL_BACK]), 20, 0.3),
        (open_loop(BUS_FAULTS["bus_off"], True), None, 0.95),
    ],
    ids=[
        "closed loop, spoofed",
        "closed loop, flooded",
        "closed loop, flooded, scored 20 ticks on",
        "closed loop, flooded, scored 20 ticks on, a bias until the tick scored whole again",
        "open loop, bus-off",
    ],
)
def test_a_tick_scored_whole_on_arrays_where_its_answers_came_at_once_scores_as_alone(
    loaded,
    window,
    whole,
    taps,  # noqa: F811 (the fixture)
    monkeypatch,
):
    """Where a tick's answers came at once on a quiet wire and the scorer holds no other tick, the
    batch scores the tick whole from its arrays (``TickBatch``); elsewhere the scorer takes its
    parts as the log would hold them: a flood's ticks, and every tick after it while the ticks
    whose estimates it starved wait in the scorer (alone, they are scored when ``WINDOW`` ticks
    old), and each run's last tick. Both ways in one run, every score as alone
    (``assert_batched_as_alone`` compares the rows). ``whole``: the least share of ticks scored
    whole; with a ``window`` of 20 ticks the starved ticks are scored 20 ticks on and the runs go
    back to ticks scored whole, through faults that changed meanwhile."""
    from cosim.analysis.metrics import scorer
    from cosim.campaign.batch_wire import WireBatch
    from cosim.campaign.run_wire import RunWire

    if window is not None:
        monkeypatch.setattr(scorer, "WINDOW", window)  # alone as batched

    scored, ways, last = WireBatch._scored_whole, Counter(), {}

    def counted(self, k, verdicts, steady):
        rows = [r for r, _ in verdicts] + steady.tolist()
        ways["whole"] += len(rows)
        ways["steady"] += len(steady)
        ways["back"] += sum(last.get(r) == "parts" for r in rows)
        last.update((r, "whole") for r in rows)
        return scored(self, k, verdicts, steady)

    give = RunWire._give_truth

    def given(self):
        if self.held is not None:
            ways["parts"] += 1
            last[self.held[2]] = "parts"
        return give(self)

    from cosim.campaign.steady_wire import SteadyWires

    by_parts = SteadyWires.score

    def steady_parts(self, k, rows, truth):  # a steady tick's parts, from the arrays
        found = by_parts(self, k, rows, truth)
        ways["parts"] += len(found)
        last.update((r, "parts") for r in found)
        return found

    monkeypatch.setattr(WireBatch, "_scored_whole", counted)
    monkeypatch.setattr(RunWire, "_give_truth", given)
    monkeypatch.setattr(SteadyWires, "score", steady_parts)
    assert_batched_as_alone(loaded, taps)
    ticks = len(SEEDS) * loaded.scenario.ticks
    assert ways["whole"] + ways["parts"] == ticks  # every tick scored once, one way or the other
    assert ways["whole"] >= whole * ticks and ways["parts"] >= len(SEEDS), ways
    assert ways["back"] == (len(SEEDS) if window is not None else 0), ways
