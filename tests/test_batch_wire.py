"""The arbitrated bus of a batch (cosim.campaign.batch_wire): the attacks of the taxonomy in a closed
loop and the faults of the bus itself in an open loop, with and without the intrusion detector,
stepped together for K runs, give each run exactly what it gives alone: beyond its metrics row, what
each of its nodes takes in every tick (the readings, NaN where missing, and commands its estimators
and controller are handed) and the detector's verdict on every tick."""

from __future__ import annotations

import copy
from collections import Counter, defaultdict
from typing import Any

import numpy as np
import pytest

import cosim.campaign.batch as batch_module
import cosim.campaign.batch_estimators as batch_estimators
from cosim import api
from cosim.analysis.metrics.scorer import Scorer
from cosim.campaign.batch import refusal, run_batch, run_together
from cosim.campaign.results import rows_of
from cosim.errors import CodecError
from cosim.run.detector import IntrusionDetector
from cosim.run.node import ControllerNode, EstimatorNode
from cosim.run.plan import RunPlan
from cosim.scenario import apply

SEEDS = [3, 4]
WINDOW = {"start": 0.3, "end": 0.9}
# the attacks of masses-attack-taxonomy, moved into 1.2 s
TAXONOMY = {
    "none": [],
    "flooding": [{"name": "flooding", "kind": "babbling_node", "id": 0x000, "period": 0.00025, **WINDOW}],
    "injection": [{"name": "injection", "kind": "spoofing", "message": "SENSOR_x2", "value": 0.8, **WINDOW}],
    "fuzzing": [{"name": "fuzzing", "kind": "fuzzing", "low": 0x000, "high": 0x7FF, "period": 0.0005, **WINDOW}],
    "suspension": [{"name": "suspension", "kind": "suspension", "messages": ["SENSOR_x2"], **WINDOW}],
    "masquerade": [{"name": "masquerade", "kind": "masquerade", "message": "SENSOR_x2", "offset": 0.2, **WINDOW}],
    "replay": [{"name": "replay", "kind": "replay", "message": "SENSOR_x2", "lag": 0.25, **WINDOW}],
}
# the faults of masses-bus-faults, moved into 1.2 s
BUS_FAULTS = {
    "babbling": [{"name": "babbling", "kind": "babbling_node", "id": 0x0C0, "period": 0.0011, "length": 8, **WINDOW}],
    "bus_off": [{"name": "bus_off", "kind": "bus_off", "node": "plant", "recover": True, **WINDOW}],
    "loss_x1": [{"name": "loss_x1", "kind": "frame_loss", "messages": ["SENSOR_x1"], "probability": 0.3, **WINDOW}],
}


def closed_loop(faults):
    """masses-pid-can (PID on x2, 500 kbit/s arbitrated classic CAN, the detector on) under ``faults``."""
    return apply(api.load("masses-pid-can"), [("duration", 1.2), ("faults", faults)])


def open_loop(faults, detector, traffic=()):
    """masses-bus-overload (125 kbit/s arbitrated, 95 % load) under ``faults``, its chatty node's
    ``traffic`` only where given."""
    settings = [
        ("duration", 1.2),
        ("bus.traffic", list(traffic)),
        ("faults", faults),
        ("bus.intrusion_detector", detector),
    ]
    return apply(api.load("masses-bus-overload"), settings)


# masses-bus-overload's chatty node from 0.3 s, every 4 ms: offered load about 120 %, the
# estimators' frames and the nodes' heartbeats (the lowest priorities) contend for what is left of
# the wire, so when each heartbeat goes decides which estimates get through (its own period, 1.1 ms,
# leaves the heartbeats no room at all: they never go, and change nothing)
CHATTY = [{"name": "chatty", "id": 0x0C0, "period": 0.004, "length": 8, "start": 0.3}]


class Taps:
    """What each run's nodes hand their estimator or controller in every tick (readings, commands),
    and every verdict of each run's intrusion detector, by run (a run alone: run 0)."""

    def __init__(self) -> None:
        self.inputs: defaultdict[tuple[int, str], list[Any]] = defaultdict(list)
        self.detectors: list[IntrusionDetector] = []
        self.scorers: list[Scorer] = []  # each with the detector's verdicts it scored, tick by tick

    def add(self, run: int, node: str, *values: Any) -> None:
        self.inputs[(run, node)].append(tuple(v.tolist() if isinstance(v, np.ndarray) else v for v in values))

    def of(self, run: int) -> dict[str, Any]:
        found: dict[str, Any] = {node: values for (r, node), values in self.inputs.items() if r == run}
        found["verdicts"] = self.detectors[run].history if self.detectors else None
        found["scored"] = self.scorers[run].verdicts
        return found


class _Recorded:
    """A batched step that records the rows it is handed."""

    def __init__(self, step, record):
        self._step, self._record = step, record

    def step(self, *args):
        self._record(*args)
        return self._step(*args)


@pytest.fixture
def taps(monkeypatch):
    found = Taps()
    _tap_nodes(monkeypatch, found)
    _tap_batch(monkeypatch, found)
    init, verdicts = IntrusionDetector.__init__, IntrusionDetector.verdicts

    def created(self, *args, **kwargs):
        init(self, *args, **kwargs)
        self.history = []
        found.detectors.append(self)

    def given(self, until):
        out = verdicts(self, until)
        self.history += out
        return out

    monkeypatch.setattr(IntrusionDetector, "__init__", created)
    monkeypatch.setattr(IntrusionDetector, "verdicts", given)
    scorer_init, score_bus = Scorer.__init__, Scorer.score_bus

    def scorer_created(self, *args, **kwargs):
        scorer_init(self, *args, **kwargs)
        self.verdicts = []
        found.scorers.append(self)

    def scored(self, k, ids, rejected, active):
        if ids is not None:  # a batch without a detector scores no verdict (``TickBatch``): there is none
            self.verdicts.append((k, ids))
        return score_bus(self, k, ids, rejected, active)

    monkeypatch.setattr(Scorer, "__init__", scorer_created)
    monkeypatch.setattr(Scorer, "score_bus", scored)
    return found


def _tap_nodes(monkeypatch, found):
    """Alone: what the nodes hand their estimator (y, u) and controller (y, the report)."""
    estimator_answer, controller_answer = EstimatorNode.answer, ControllerNode.answer

    def answer_estimator(self, tick):
        step = self.estimator.step
        self.estimator.step = lambda y, u: found.add(0, self.client.name, y, u) or step(y, u)
        try:
            estimator_answer(self, tick)
        finally:
            del self.estimator.step

    def answer_controller(self, tick):
        step = self.controller.step
        self.controller.step = lambda y, t, report: (
            found.add(0, "controller", y, sorted(report.items())) or step(y, t, report)
        )
        try:
            controller_answer(self, tick)
        finally:
            del self.controller.step

    monkeypatch.setattr(EstimatorNode, "answer", answer_estimator)
    monkeypatch.setattr(ControllerNode, "answer", answer_controller)


def _tap_batch(monkeypatch, found):
    """Batched: the rows each estimator's and the controller's batched step is handed."""
    estimators_given, controller_step = batch_estimators.Estimators.given, batch_module._Controller.step

    def given_estimators(self, y, u_cmd, commanded):
        ys, u = estimators_given(self, y, u_cmd, commanded)  # what its batched step is handed
        for r in range(len(ys)):
            found.add(r, self.name, ys[r], u[r])
        return ys, u

    def step_controller(self, k, readings, given, runs, alive):
        inner = self.batch
        assert inner is not None  # the PID's batched step
        record = lambda ys, t, reports: [  # noqa: E731
            found.add(r, "controller", ys[r], sorted(reports[r].items())) for r in np.flatnonzero(alive)
        ]
        self.batch = _Recorded(inner.step, record)
        try:
            return controller_step(self, k, readings, given, runs, alive)
        finally:
            self.batch = inner

    monkeypatch.setattr(batch_estimators.Estimators, "given", given_estimators)
    monkeypatch.setattr(batch_module._Controller, "step", step_controller)


def objects_only(monkeypatch):
    """No run of a batch goes steady: every tick of its bus is its objects' (``cosim.campaign.steady_wire``)."""
    monkeypatch.setattr("cosim.campaign.steady_wire.SteadyWires._enters", lambda self, r, k: False)


def assert_batched_as_alone(loaded, taps, seeds=SEEDS):
    """Each run's row, frames lost, contested ticks, every score of the detector, and what each of
    its nodes took and its detector said in every tick, exactly as alone."""
    runs = run_batch(loaded, seeds)
    assert [run.left for run in runs] == [""] * len(seeds)
    batched = copy.copy(taps.inputs), list(taps.detectors), list(taps.scorers)
    for r, (seed, run) in enumerate(zip(seeds, runs)):
        taps.inputs.clear()
        taps.detectors.clear()
        taps.scorers.clear()
        single = api.run(loaded, None, seed=seed, in_process=True, measure=True).metrics
        assert rows_of(run.metrics) == rows_of(single), seed  # exact: every float, every count
        assert run.metrics.warnings == single.warnings, seed  # e.g. estimates that came after their tick
        assert (run.metrics.contested_ticks, run.metrics.frames.lost) == (single.contested_ticks, single.frames.lost)
        assert (run.metrics.bus.intrusion_detection if run.metrics.bus else None) == (
            single.bus.intrusion_detection if single.bus else None
        )
        alone = taps.of(0)
        mine = {node: values for (i, node), values in batched[0].items() if i == r}
        nodes = {e.name for e in loaded.scenario.estimators} | ({"controller"} if loaded.scenario.controller else set())
        assert set(mine) == set(alone) - {"verdicts", "scored"} == nodes, seed
        for node in mine:
            assert len(mine[node]) == len(alone[node]) == loaded.scenario.ticks, node
            for k, (a, b) in enumerate(zip(mine[node], alone[node])):
                assert _same(a, b), (seed, node, k, a, b)
        # every verdict scored, tick by tick; the detector's own where it gave them (a steady tick's
        # is on arrays, ``cosim.campaign.steady_wire``), with the ids it raised on
        assert batched[2][r].verdicts == alone["scored"], seed
        if batched[1]:
            assert len(alone["scored"]) == loaded.scenario.ticks and alone["verdicts"] is not None
            given = dict(((tick, repr(rest)) for tick, *rest in alone["verdicts"]))
            assert all(given[tick] == repr(rest) for tick, *rest in batched[1][r].history), seed
    return runs


def _same(a, b):
    """Equal, NaN where NaN (a missing reading)."""
    return repr(a) == repr(b)


@pytest.mark.parametrize("attack", sorted(TAXONOMY))
def test_each_attack_of_the_taxonomy_batched_gives_what_each_node_takes_and_the_detector_says_alone(attack, taps):
    loaded = closed_loop(TAXONOMY[attack])
    assert refusal(RunPlan.build(loaded, 0, interface="virtual")) is None
    assert_batched_as_alone(loaded, taps)


@pytest.mark.parametrize("detector", [False, True])
@pytest.mark.parametrize("fault", sorted(BUS_FAULTS))
def test_each_fault_of_the_bus_batched_gives_what_each_node_takes_and_the_detector_says_alone(fault, detector, taps):
    assert_batched_as_alone(open_loop(BUS_FAULTS[fault], detector), taps)


@pytest.mark.parametrize("detector", [False, True])
def test_a_fuzzers_frame_of_an_estimators_message_in_a_quiet_tick_is_scored_as_alone(detector, taps):
    """A fuzzer on an estimator's id once a tick, at its start (the wire stays quiet), with the
    payload of that estimator's frame of tick 50: alone, the scorer reads each as the estimator's
    estimate (of a tick already scored: counted late); batched, a tick with it is not scored whole
    (found by a review: it was, and the fuzzer's frames were missing from the scores)."""
    codec = api.load("masses-pid-can").scenario.codec()
    payload = bytes(codec.encode("EST_kalman_0", 50, [5.0, -5.0]).data).hex()
    frame_id = codec.specs["EST_kalman_0"].frame_id
    fuzz = {"name": "fuzz", "kind": "fuzzing", "low": frame_id, "high": frame_id, "length": 8, "payload": payload}
    loaded = apply(closed_loop([{**fuzz, "period": 0.01, **WINDOW}]), [("bus.intrusion_detector", detector)])
    runs = assert_batched_as_alone(loaded, taps)
    assert all("arrived after their tick was scored" in " ".join(run.metrics.warnings) for run in runs)


def test_the_control_frames_a_runs_nodes_verify_alike_are_verified_once_a_tick_as_each_would(taps, monkeypatch):
    """A run's nodes taking their ticks whole verify the tick's SYNC and their upstream nodes'
    heartbeats under the same keys: the batch verifies each once a tick (``RunWire._verifies``), and
    every answer it gives a node is the one the node's own ``ControlAuth.verify`` gives."""
    from cosim.campaign.run_wire import RunWire

    verifies, asked = RunWire._verifies, Counter()

    def checked(self, control, frame, near):
        shared = (id(frame), near, id(control.key_of(frame))) in self.verified  # held: the very frame
        found = verifies(self, control, frame, near)
        assert found == (control.verify(frame, near) is None)
        asked["shared" if shared else "verified"] += 1
        return found

    monkeypatch.setattr(RunWire, "_verifies", checked)
    loaded = closed_loop(TAXONOMY["injection"])
    assert_batched_as_alone(loaded, taps)
    assert asked["shared"] > asked["verified"] > 0, asked  # three nodes share SYNC, two the controller's heartbeat


_TRAFFIC_STATE = ("pending", "closed", "joined", "left", "lost", "late", "data", "missed_by", "_lost_carried")
_TRAFFIC_STATE += ("received", "contested", "_counts", "commands", "_distrusted", "rejected", "foreign_frames")


@pytest.mark.parametrize(
    "loaded",
    [closed_loop(TAXONOMY["injection"]), open_loop(BUS_FAULTS["babbling"], True)],
    ids=["closed loop, spoofed", "open loop, babbling node"],
)
def test_the_nodes_answers_heard_at_once_leave_the_runners_traffic_as_heard_one_by_one(loaded, monkeypatch):
    """``Traffic.answered`` (the nodes' answers to a tick, as their clients sent them) against the
    same frames heard one by one and flushed, from the same state, wherever a batch takes them at
    once: every count, what each node's heartbeat carried, what goes on to the wire and in which
    order. Elsewhere (the first tick, a tick whose answers are not whole) they go one by one."""
    from cosim.run.traffic import Traffic

    answered, ways = Traffic.answered, [0, 0]

    def checked(self, closings, t, t_ns):
        twin = copy.copy(self)
        for name in _TRAFFIC_STATE:
            setattr(twin, name, copy.deepcopy(getattr(self, name)))
        ours, theirs = [], []
        self.deliver, deliver = (lambda *item: ours.append(item) or deliver(*item)), self.deliver
        try:
            taken = answered(self, closings, t, t_ns)
        finally:
            self.deliver = deliver
        ways[taken] += 1
        if taken:
            twin.deliver = lambda *item: theirs.append(item)
            for frames in closings:
                for frame, _ in frames:
                    twin.on_message_received(frame)
            twin.flush(twin.current, t, t_ns)
            for name in _TRAFFIC_STATE:
                assert getattr(self, name) == getattr(twin, name), name
            assert [(i[:3], i[3], i[4]) for i in ours] == [(i[:3], i[3], i[4]) for i in theirs]
        return taken

    from cosim.campaign.run_wire import RunWire

    heard, at_once = RunWire._heard_answers, [0, 0]

    def counted(self, k):
        found = heard(self, k)
        at_once[found] += 1
        return found

    monkeypatch.setattr(Traffic, "answered", checked)
    monkeypatch.setattr(RunWire, "_heard_answers", counted)
    objects_only(monkeypatch)  # every tick through the runs' objects, none steady (``steady_wire``)
    runs = run_batch(loaded, SEEDS)
    assert [run.left for run in runs] == [""] * len(SEEDS)
    assert ways[True] > 150 and at_once[True] == ways[True] and at_once[False] >= len(SEEDS), (ways, at_once)


def test_a_fuzzers_frames_too_short_for_a_control_frames_mac_time_as_they_are_batched_as_alone(taps):
    # 2-byte frames on the ids around SYNC's (its MAC from byte 5): the wire times them as they
    # are (it raised ValueError before, alone and batched)
    short = {"name": "fuzzing", "kind": "fuzzing", "low": 0x07F, "high": 0x081, "length": 2, "period": 0.0005}
    assert_batched_as_alone(closed_loop([{**short, **WINDOW}]), taps)


def test_a_fuzzers_heartbeats_held_back_by_a_flood_batched_as_alone(taps):
    # the wire delivers them in later ticks, as forged (the runner signs none of an intruder's)
    faults = [
        {"name": "flood", "kind": "babbling_node", "id": 0x001, "period": 0.0003, **WINDOW},
        {"name": "fuzz", "kind": "fuzzing", "low": 0x700, "high": 0x703, "length": 8, "period": 0.0004, **WINDOW},
    ]
    assert_batched_as_alone(closed_loop(faults), taps)


def test_an_overloaded_wire_with_background_traffic_batched_gives_what_each_node_takes_alone(taps):
    assert_batched_as_alone(open_loop(BUS_FAULTS["loss_x1"], True, CHATTY), taps)


def test_the_equalities_are_not_vacuous(taps):
    """What the attacks and faults above do, alone: readings missing where frames come late, are
    lost or are second copies, late frames counted, ticks contested, the detector's checks raised."""
    found = {}
    for name, loaded in [
        ("flooding", closed_loop(TAXONOMY["flooding"])),
        ("injection", closed_loop(TAXONOMY["injection"])),
        ("fuzzing", closed_loop(TAXONOMY["fuzzing"])),
        ("babbling", open_loop(BUS_FAULTS["babbling"], True)),
        ("bus_off", open_loop(BUS_FAULTS["bus_off"], False)),
    ]:
        taps.inputs.clear()
        metrics = api.run(loaded, None, seed=3, in_process=True, measure=True).metrics
        missing = sum("nan" in repr(y) for y, _ in taps.of(0)["kalman"])
        scores = metrics.bus.intrusion_detection if metrics.bus else None
        raised = sorted(c for c, score in (scores or {}).items() if any(f.detected for f in score.faults.values()))
        found[name] = (metrics.frames.lost, metrics.contested_ticks, missing, raised)
    assert found["flooding"][0] > 0 and found["flooding"][2] > 50 and "unknown" in found["flooding"][3]
    assert found["injection"][1:] == (60, 60, ["any", "period", "sequence"])
    assert found["fuzzing"][1] > 0 and "unknown" in found["fuzzing"][3]
    assert found["babbling"][2] > 50 and found["babbling"][3] == ["any", "unknown"]
    assert found["bus_off"][2] == 60 and found["bus_off"][3] == []


def test_a_controller_reading_a_diagnosis_node_over_an_arbitrated_can_fd_wire_batched_as_alone(taps):
    """The vessel's thrust allocation reads the COFD node's report of the tick before, on a CAN FD
    wire at 1 Mbit/s with the detector: what each node takes (the report too) as alone."""
    settings = [("duration", 1.0), ("bus.timing", "arbitrated"), ("bus.bitrate", 1_000_000)]
    loaded = apply(api.load("vessel-reconfiguration"), [*settings, ("bus.intrusion_detector", True)])
    assert_batched_as_alone(loaded, taps)


def test_a_run_whose_intruder_forges_what_its_frame_cannot_carry_leaves_the_batch_and_ends_as_alone():
    spoofed = closed_loop(TAXONOMY["injection"])
    out_of_range = closed_loop([{**TAXONOMY["injection"][0], "value": 50.0, "start": 0.4}])
    members = [(spoofed, 3), (out_of_range, 4), (spoofed, 5)]
    runs = run_together(members)
    assert not any(run.refused for run in runs)
    assert runs[1].metrics is None and runs[1].left.startswith("tick 40: ")
    assert "SENSOR_x2.x2 at tick 40 = 50 m is outside" in runs[1].left
    for (loaded, seed), run in zip(members[::2], runs[::2]):
        single = api.run(loaded, None, seed=seed, in_process=True, measure=True).metrics
        assert not run.left and rows_of(run.metrics) == rows_of(single)
    with pytest.raises(CodecError, match="SENSOR_x2.x2 at tick 40 = 50 m is outside"):  # alone: its error
        api.run(out_of_range, None, seed=4, in_process=True, measure=True)


def test_secoc_on_an_arbitrated_wire_is_refused_in_one_line():
    secured = apply(closed_loop([]), [("bus.fd", True), ("bus.authentication", "secoc")])
    plan = RunPlan.build(secured, 0, interface="virtual")
    assert refusal(plan) == "its frames are authenticated (SecOC) on an arbitrated wire"


def test_the_pids_batched_step_equals_its_single_steps_through_missing_readings_and_saturation():
    plan = RunPlan.build(closed_loop([]), 0, interface="virtual")
    runs = 5
    single = [copy.deepcopy(plan.controller) for _ in range(runs)]
    batched = type(plan.controller).batched([copy.deepcopy(plan.controller) for _ in range(runs)])
    rng = np.random.default_rng(1)
    saturated = 0
    for k in range(300):
        y = rng.normal(0.5, 2.0, (runs, 3))
        y[rng.random((runs, 3)) < 0.2] = np.nan
        u, diagnostics = batched.step(y, k * 0.01, [{}] * runs)
        for r, controller in enumerate(single):
            command = controller.step(y[r], k * 0.01, {})
            assert u[r].tolist() == command.u.tolist(), (k, r)
            assert {name: values[r] for name, values in diagnostics.items()} == command.diagnostics, (k, r)
            saturated += abs(command.u[0]) == 20.0
    assert saturated > 50


@pytest.mark.slow
@pytest.mark.parametrize("name", ["masses-bus-faults", "masses-attack-taxonomy"])
def test_the_arbitrated_campaigns_with_their_faults_in_1_2_s_batched_give_the_table_of_one_at_a_time(tmp_path, name):
    """The campaign as the benchmark runs it (coordinator, worker, parts, table), its faults moved
    into 1.2 s runs, batched against --batch 1: the same table."""
    import pyarrow.parquet as pq
    import tomlkit

    from cosim.campaign.coordinator import run_campaign
    from cosim.campaign.results import NONDETERMINISTIC
    from cosim.campaign.spec import load_campaign
    from cosim.scenario import parse_setting

    document = tomlkit.parse(load_campaign(name).text)
    faults = next(axis for axis in document["axes"] if axis["key"] == "faults")
    for value in faults["values"]:
        for fault in value:
            fault.update(WINDOW)
    path = tmp_path / f"{name}.toml"
    path.write_text(tomlkit.dumps(document))
    campaign = load_campaign(path, seeds=2, settings=[parse_setting("duration=1.2")])
    tables = {
        b: run_campaign(campaign, tmp_path / f"b{b}", engine="inline", keep_logs="none", batch=b) for b in (1, None)
    }
    assert tables[None].batched == tables[None].runs and tables[1].batched == 0
    one, batched = (pq.read_table(tables[b].path).drop(list(NONDETERMINISTIC)) for b in (1, None))
    assert one.equals(batched)
