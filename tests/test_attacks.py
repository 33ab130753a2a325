"""The attack kinds of the taxonomy (``faults.attacks``): suspension, masquerade and fuzzing, through
the bus fault stage's generic interface, and each intruder frame labelled on ``/cosim/foreign`` by
its place on ``/can/frames``."""

from __future__ import annotations

import numpy as np
import pytest

import faults as fm
from cosim import scenario
from cosim.bus.codec import Codec
from cosim.errors import ScenarioError
from cosim.log.reader import LogReader
from cosim.run import run
from cosim.run.busfaults import BusFaultStage, counted_by_receivers
from cosim.scenario.faults import build_bus_faults
from faults.attacks import Fuzzing, Masquerade, Suspension
from tests.snippets import masses

DT_NS = 10_000_000


def _stage(models, arbitrated=False):
    codec = scenario.parse(masses("a", forced=True, kalman=True), "a.toml").codec()
    return codec, BusFaultStage(codec, models, 7, DT_NS, 500_000, arbitrated)


def _tick(codec: Codec, k: int, x2: float = 0.25):
    frames = [codec.encode_decoded(name, k, (value,)) for name, value in (("SENSOR_x1", 0.1), ("SENSOR_x2", x2))]
    sync = codec.sync(k, len(frames))
    return [(sync, codec.decode(sync)), *frames]


def test_the_attack_kinds_resolve_through_the_registry_of_fault_kinds():
    assert fm.FAULT_MODELS["masquerade"] is Masquerade
    assert fm.FAULT_MODELS["suspension"] is Suspension
    assert fm.FAULT_MODELS["fuzzing"] is Fuzzing
    assert fm.FAULT_MODELS.origin("masquerade").source == "built-in"


def test_a_masquerade_sends_in_the_genuine_slot_with_its_counter_and_the_bias():
    model = Masquerade(channels=(), start=0.0, label="mq", message="SENSOR_x2", offset=(0.2,), rate=(0.1,))
    codec, stage = _stage([model])
    applied = stage.apply(50, _tick(codec, 50))
    sync, x1, x2 = applied.frames
    assert sync[1].values["frames"] == 2  # the forgery is the only copy: receivers count it
    assert x1[1].spec.name == "SENSOR_x1" and id(x1) not in applied.intruders
    assert x2[1].spec.name == "SENSOR_x2" and applied.intruders[id(x2)] == "mq"
    assert x2[1].tick == 50  # the next counter: timing and sequence say nothing
    assert x2[1].values["x2"] == pytest.approx(0.25 + 0.2 + 0.1 * 0.5, abs=1e-6)
    assert [(e.label, e.message, e.event) for e in applied.events] == [
        ("mq", "SENSOR_x2", "lost"),
        ("mq", "SENSOR_x2", "injected"),
    ]


def test_a_masquerade_with_a_value_sends_it_and_a_suspension_sends_nothing():
    value = Masquerade(channels=(), label="mq", message="SENSOR_x2", value=(0.7,))
    codec, stage = _stage([value])
    assert stage.apply(3, _tick(codec, 3)).frames[2][1].values["x2"] == pytest.approx(0.7, abs=1e-6)
    silenced = Suspension(channels=(), label="su", messages=("SENSOR_x2",))
    codec, stage = _stage([silenced])
    applied = stage.apply(3, _tick(codec, 3))
    assert [f[1].spec.name for f in applied.frames] == ["SYNC", "SENSOR_x1"] and not applied.intruders
    assert applied.frames[0][1].values["frames"] == 1


def test_fuzzing_draws_ids_in_its_range_at_its_period_from_its_own_stream():
    def frames(seed_stage):
        model = Fuzzing(channels=(), start=0.001, label="fz", low=0x100, high=0x10F, period=0.003, length=8)
        codec, stage = _stage([model], arbitrated=True)
        stage.__init__(codec, [model], seed_stage, DT_NS, 500_000, True)
        applied = stage.apply(0, _tick(codec, 0))
        forged = [f for f in applied.frames if id(f) in applied.intruders]
        return applied, forged

    applied, forged = frames(7)
    assert len(forged) == 3  # at 1, 4 and 7 ms of the tick [0, 10) ms
    assert [applied.delays_ns[id(f)] for f in forged] == [1_000_000, 4_000_000, 7_000_000]
    assert all(0x100 <= f[0].arbitration_id <= 0x10F and len(f[0].data) == 8 for f in forged)
    again = [bytes(f[0].data) for f in frames(7)[1]]
    assert [bytes(f[0].data) for f in forged] == again
    assert [bytes(f[0].data) for f in frames(8)[1]] != again


def test_fuzzing_with_a_payload_sends_it_in_every_frame_at_random_ids_as_roads_fuzzing():
    def forged(payload):
        model = Fuzzing(channels=(), start=0.0, label="fz", period=0.001, payload=payload)
        codec, stage = _stage([model], arbitrated=True)
        stage.__init__(codec, [model], 7, DT_NS, 500_000, True)
        applied = stage.apply(0, _tick(codec, 0))
        return [(f[0].arbitration_id, bytes(f[0].data)) for f in applied.frames if id(f) in applied.intruders]

    road = forged(b"\xff" * 8)
    assert len(road) == 10 and {data for _, data in road} == {b"\xff" * 8} and len({i for i, _ in road}) > 1
    spec = scenario.parse(
        masses("a", forced=True, kalman=True) + '[[faults]]\nkind = "fuzzing"\npayload = "ff00FF"\n', "f.toml"
    )
    assert build_bus_faults(spec)[0].payload == bytes.fromhex("ff00ff")


def test_receivers_count_the_frames_of_the_tick_they_take():
    codec, _ = _stage([])
    tick = _tick(codec, 9)[1:]
    stale = codec.encode_decoded("SENSOR_x1_minus_x2", 8, (0.0,))  # a fuzzer's frame with another counter
    copy = codec.encode_decoded("SENSOR_x1", 9, (0.3,))
    counted = counted_by_receivers([*tick, stale, copy], {}, False, 9)
    assert counted == tick


def test_the_attack_tables_are_checked(tmp_path):
    base = masses("a", forced=True, kalman=True)
    bad = {
        'kind = "masquerade"\nmessage = "SENSOR_x9"': "is not a message the runner sends",
        'kind = "masquerade"\nmessage = "SENSOR_x2"\noffset = [0.1, 0.2]': r"offset: SENSOR_x2 carries 1 signal",
        'kind = "fuzzing"\nlow = 0x200\nhigh = 0x100': "must not exceed high",
        'kind = "fuzzing"\npayload = "FFF"': "'FFF' is not up to 8 bytes of two hex digits each",
        'kind = "fuzzing"\npayload = "' + "00" * 9 + '"': "is not up to 8 bytes",
        'kind = "suspension"\nmessages = []': "messages",
    }
    for table, message in bad.items():
        with pytest.raises(ScenarioError, match=message):
            scenario.parse(base + f"[[faults]]\n{table}\n", "bad.toml")


def test_intruder_frames_are_labelled_by_their_place_on_the_bus(tmp_path):
    faults = """
[[faults]]
name = "mq"
kind = "masquerade"
message = "SENSOR_x2"
offset = 0.2
start = 0.3
end = 0.6
[[faults]]
name = "fz"
kind = "fuzzing"
low = 0x100
high = 0x1FF
period = 0.0001
start = 0.7
end = 0.8
"""
    path = tmp_path / "a.toml"
    path.write_text(masses("a", 1.0, forced=True, bus='interface = "virtual"', kalman=True) + faults)
    out = tmp_path / "a.mcap"
    assert run(scenario.load(str(path)), out, 0).status == "completed"
    frames, foreign, truth = {}, [], {}
    with LogReader(out) as reader:
        for topic, _, m in reader.messages(["/can/frames", "/cosim/foreign", "/truth/faults"]):
            if topic == "/can/frames":
                frames[m["seq"]] = m
            elif topic == "/cosim/foreign":
                foreign.append(m)
            else:
                truth[m["tick"]] = m
    assert all(f["seq"] is not None for f in foreign)  # 100 fuzzing frames a tick: none only counted
    assert {f["source"] for f in foreign} == {"mq", "fz"}
    labelled = {f["seq"]: f["reason"] for f in foreign}
    for f in foreign:
        assert (frames[f["seq"]]["id"], frames[f["seq"]]["data"]) == (f["id"], f["data"])
    masquerade = sorted(s for s, reason in labelled.items() if "fault mq" in reason)
    x2 = [m for m in frames.values() if m["message"] == "SENSOR_x2"]
    assert len(x2) == 100  # one a tick: the genuine ones, then the masquerader's in their place
    assert masquerade == [m["seq"] for m in x2 if 30 <= m["tick"] < 60]
    assert all("mq" in truth[k]["active"] for k in range(30, 60)) and "mq" not in truth[60]["active"]
    fuzzed = [s for s, reason in labelled.items() if "fault fz" in reason]
    assert len(fuzzed) == 10 * 100 and {frames[s]["tick"] for s in fuzzed} == set(range(70, 80))
    assert np.all([0x100 <= frames[s]["id"] <= 0x1FF for s in fuzzed])


PLUGIN = '''
from dataclasses import dataclass

from cosim.api import BusFault, FrameFate


@dataclass
class Stutter(BusFault):
    """Every other frame of its messages lost, and a copy of the message with ``value`` after each."""

    value: float = 0.0
    kind = "stutter"
    intruder = True
    attack = "fabrication"

    def reset(self, rng):
        super().reset(rng)
        self.seen = 0

    def fate(self, message, t):
        self.seen += 1
        return FrameFate(lost=self.seen % 2 == 0)

    def inject(self, t):
        return [(m, (self.value,)) for m in self.messages]
'''


def test_a_plugins_bus_fault_acts_through_the_same_interface(tmp_path):
    (tmp_path / "stutter.py").write_text(PLUGIN)
    table = '[[faults]]\nname = "st"\nkind = "stutter.py:Stutter"\nstart = 0.2\nend = 0.4\n'
    path = tmp_path / "p.toml"
    path.write_text(
        masses("p", 0.6, forced=True, bus='interface = "virtual"')
        + table
        + 'params = { messages = ["SENSOR_x1"], value = 0.3 }\n'
    )
    out = tmp_path / "p.mcap"
    assert run(scenario.load(str(path)), out, 0).status == "completed"
    with LogReader(out) as reader:
        events = [m for _, _, m in reader.messages(["/truth/bus_faults"])]
        foreign = [m for _, _, m in reader.messages(["/cosim/foreign"])]
    assert sum(e["event"] == "lost" for e in events) == 10 and sum(e["event"] == "injected" for e in events) == 20
    assert len(foreign) == 20 and {f["source"] for f in foreign} == {"st"}
    bad = masses("p", forced=True) + table + 'params = { messages = ["SENSOR_x9"] }\n'
    with pytest.raises(
        ScenarioError, match=r"faults\[0\]\.params\.messages: 'SENSOR_x9' is not a message the runner sends"
    ):
        scenario.parse(bad, "bad.toml", tmp_path)
