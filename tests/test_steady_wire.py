"""Steady ticks of a batch's arbitrated buses (``cosim.campaign.steady_wire``): a run whose tick is
steady goes on arrays, and where it is not, its objects are brought to the state its own ticks
would have left them in. Held here against the objects themselves, tick by tick, and against the
run alone."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import cosim.campaign.steady_wire as steady_wire
from cosim import api
from cosim.campaign.batch import run_batch
from cosim.campaign.batch_wire import WireBatch
from cosim.campaign.run_wire import RunWire
from cosim.campaign.steady_wire import SteadyWires
from cosim.scenario import apply
from tests.test_batch_wire import (
    BUS_FAULTS,
    SEEDS,
    TAXONOMY,
    assert_batched_as_alone,
    closed_loop,
    objects_only,
    open_loop,
    taps,  # noqa: F401 (a fixture)
)


def _frames(codec, frames) -> list[tuple[int, bytes]]:
    """Frames by id and bytes, a control frame's MAC at 0 (each batch's runs have keys of their own)."""
    out = []
    for frame in frames:
        data = bytearray(frame.data)
        control = codec.control_macs.get(frame.arbitration_id)
        if control is not None:
            data[control[1].mac[0] :] = bytes(len(data) - control[1].mac[0])
        out.append((frame.arbitration_id, bytes(data)))
    return out


def state(run: RunWire) -> dict[str, Any]:
    """What of a run's objects the next tick depends on: its wire, the runner's traffic, each node's
    client and channel, the detector, the bus faults, the scorer, the truth held."""
    codec, arbitration, traffic, detector = run.codec, run.arbitration, run.traffic, run.detector
    found: dict[str, Any] = {
        "wire": (arbitration.wire.idle_ns, arbitration.wire._seq, len(arbitration.wire.queue), arbitration._inputs_ns),
        "in flight": (len(arbitration._answers), len(arbitration._runner), len(arbitration._on_channel)),
        "runner hears": _frames(codec, run.bus.waiting()),
        "marker": (run.marker, list(run.answering), run.rejected, run.held[0] if run.held else None),
        "truth": (run.held[2], run.held[4], run.held[1][run.held[2]].tolist()) if run.held else None,
    }
    for name in (
        "closed",
        "joined",
        "left",
        "lost",
        "late",
        "data",
        "missed_by",
        "_lost_carried",
        "received",
        "contested",
        "_counts",
        "commands",
        "current",
        "rejected",
        "foreign_frames",
        "own_foreign",
        "repeated_bootups",
    ):
        found[f"traffic.{name}"] = repr(getattr(traffic, name))
    found["traffic.pending"] = len(traffic.pending)
    for name, client in run.nodes.items():
        a = client.assembler
        found[f"{name}.assembler"] = (a.pending, a.lost, a.last_sync, a.distrusted, a.contested, repr(a._heard))
        found[f"{name}.closing"] = _frames(codec, client.closing)
        found[f"{name}.hears"] = _frames(codec, client.bus.waiting())
        found[f"{name}.outbox"] = (list(client._outbox), client._published, client.stopped)
    if detector is not None:
        found["detector"] = (dict(detector._last), detector.given, detector.alarms, repr(dict(detector._alarms)))
    if run.stage is not None:
        found["stage"] = (dict(run.stage.tec), dict(run.stage.off_until), run.stage.error_frames, len(run.stage._held))
        for model in run.stage.models:  # what it recorded (a replay), its random stream's state
            found[f"stage.{model.label}"] = repr({k: v for k, v in vars(model).items() if k != "_rng"})
            found[f"stage.{model.label}.rng"] = repr(model._rng.bit_generator.state)
    scorer = run.scorer
    found["scorer"] = (scorer.next_tick, scorer.ticks, len(scorer.pending), scorer.expected_parts)
    return found


class _Recording:
    """Each run's objects' ``state`` at the start of each tick's ``send`` (and of ``finish``), by
    (run, tick)."""

    def __init__(self) -> None:
        self.states: dict[tuple[int, int], dict[str, Any]] = {}


def _record_objects(monkeypatch, recording: _Recording) -> None:
    send, finish = WireBatch.send, WireBatch.finish

    def sending(self, k, measured, sent, commands, alive):
        for r in np.flatnonzero(alive).tolist():
            recording.states[(r, k)] = state(self.runs[r])
        return send(self, k, measured, sent, commands, alive)

    def finishing(self, r, ticks):
        recording.states[(r, ticks)] = state(self.runs[r])
        return finish(self, r, ticks)

    monkeypatch.setattr(WireBatch, "send", sending)
    monkeypatch.setattr(WireBatch, "finish", finishing)


def _record_materialized(monkeypatch, recording: _Recording, every: int) -> None:
    """Each run's objects' ``state`` where a steady run is brought back to them, with a steady run
    made to leave its arrays every few ticks (as a bus fault's window would)."""
    materialize, until = SteadyWires.materialize, steady_wire._quiet_until

    def materialized(self, r, k, truth=None):
        materialize(self, r, k, truth)
        recording.states[(r, k)] = state(self.runs[r])

    def soon(run, k, ticks):
        found = until(run, k, ticks)
        return found if k > ticks - 10 else min(found, k + every + k % 5)  # steady at the end: ``finish``

    monkeypatch.setattr(SteadyWires, "materialize", materialized)
    monkeypatch.setattr(steady_wire, "_quiet_until", soon)


CASES = {
    "closed loop": closed_loop(TAXONOMY["none"]),
    "closed loop, spoofed": closed_loop(TAXONOMY["injection"]),
    "closed loop, flooded": closed_loop(TAXONOMY["flooding"]),
    "closed loop, replayed": closed_loop(TAXONOMY["replay"]),
    "open loop, detector": open_loop(BUS_FAULTS["loss_x1"], True),
    "open loop, bus-off": open_loop(BUS_FAULTS["bus_off"], False),
}


@pytest.mark.parametrize("loaded", CASES.values(), ids=CASES.keys())
@pytest.mark.parametrize("every", [1, 6])
@pytest.mark.parametrize("window", [20, None], ids=["scored 20 ticks on", "scored when WINDOW old"])
def test_a_steady_run_brought_back_to_its_objects_is_in_the_state_its_own_ticks_leave(
    loaded, every, window, monkeypatch
):
    """Runs that go steady and are brought back every ``every`` to ``every`` + 4 ticks (but in
    their last ticks), and at their end: each time, every part of their objects the next tick
    depends on (the wire's times and offers, the runner's counts and what its channel holds, each
    node's assembler, answer and channel, the detector's last frame per id and its verdicts given,
    the bus faults' counters, the scorer, the truth held) is what it is at the same tick in the
    same runs whose every tick is their objects'. After a flood, the ticks whose estimates it
    starved wait in the scorer (until they are ``window`` ticks old), and the steady ticks give the
    scorer their parts (``SteadyWires.score``) until it holds no other tick."""
    from cosim.analysis.metrics import scorer

    if window is not None:
        monkeypatch.setattr(scorer, "WINDOW", window)
    objects = _Recording()
    with monkeypatch.context() as patch:
        objects_only(patch)
        _record_objects(patch, objects)
        alone = run_batch(loaded, SEEDS)
    steady = _Recording()
    with monkeypatch.context() as patch:
        _record_materialized(patch, steady, every)
        batched = run_batch(loaded, SEEDS)
    assert [run.left for run in batched] == [run.left for run in alone] == [""] * len(SEEDS)
    assert [run.metrics for run in batched] == [run.metrics for run in alone]
    ends = sum(k == loaded.scenario.ticks for _, k in steady.states)
    assert len(steady.states) >= 4 * len(SEEDS) and ends >= 1, sorted(steady.states)
    for (r, k), found in steady.states.items():
        expected = objects.states[(r, k)]
        for part in expected:
            assert found[part] == expected[part], (r, k, part)


@pytest.mark.parametrize(
    "loaded",
    [CASES["closed loop"], CASES["closed loop, replayed"], CASES["closed loop, flooded"], CASES["open loop, detector"]],
    ids=["closed", "replayed", "flooded", "open"],
)
def test_steady_runs_brought_back_every_few_ticks_give_what_they_give_alone(loaded, taps, monkeypatch):  # noqa: F811
    """The same, against each run alone: every row, what each node takes in every tick, every
    verdict scored."""
    _record_materialized(monkeypatch, _Recording(), 3)
    assert_batched_as_alone(loaded, taps)


def test_answers_whose_frames_carry_a_value_past_its_range_keep_a_run_off_steady_ticks(taps):  # noqa: F811
    """x2's estimate at ±0.7 m with a resolution of 1 mm: a node saturated at 0.7 sends 700 × 0.001
    = 0.7000000000000001, past the range, and the detector raises its range check on that frame
    when it arrives (in the next tick, or before it). A run whose objects took a tick whole with
    such an answer does not go steady on it (``_enters``), nor one whose steady answer is such
    (``answer``): the alarms and the rows are those of the run alone (found by a review: the entry
    did not check, and the range alarms of the ticks a run entered on were lost)."""
    loaded = apply(
        api.load("masses-pid-can"),
        [("duration", 2.0), ("bus.states", {"x2": {"minimum": -0.7, "maximum": 0.7, "resolution": 0.001}})],
    )
    runs = assert_batched_as_alone(loaded, taps, [3])
    assert runs[0].metrics.bus.intrusion_detection["range"].false_alarms > 0  # the case is the one described
