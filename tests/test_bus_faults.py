"""Bus faults: each kind does what it says to the runner's frames, seeded, logged and scored."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

import faults as fm
from cosim import scenario
from cosim.analysis.metrics import compute_metrics
from cosim.errors import ScenarioError
from cosim.log.reader import LogReader
from cosim.run import run
from tests.snippets import masses

FAULTS = """
[[faults]]
name = "loss"
kind = "frame_loss"
messages = ["SENSOR_x1"]
probability = 0.2
burst_length = 3
start = 0.5
end = 1.0
[[faults]]
name = "corrupt"
kind = "frame_corruption"
messages = ["SENSOR_x2"]
probability = 0.3
start = 1.0
end = 1.5
[[faults]]
name = "off"
kind = "bus_off"
recover = true
start = 1.5
end = 1.7
[[faults]]
name = "delay"
kind = "frame_delay"
messages = ["SENSOR_x1_minus_x2"]
delay = 0.012
jitter = 0.005
start = 1.8
end = 2.0
[[faults]]
name = "spoof"
kind = "spoofing"
message = "SENSOR_x1"
value = 0.5
start = 2.0
end = 2.5
[[faults]]
name = "replay"
kind = "replay"
message = "SENSOR_x2"
lag = 1.0
start = 2.5
"""


def _scenario(tmp_path, faults=FAULTS, timing="ideal"):
    path = tmp_path / "bf.toml"
    bus = f'interface = "virtual"\nbitrate = 125000\ntiming = "{timing}"'
    path.write_text(masses("bf", 3.0, forced=True, bus=bus, kalman=True) + faults)
    return scenario.load(str(path))


def _events(path):
    with LogReader(path) as reader:
        return [m for _, _, m in reader.messages(["/truth/bus_faults"])]


@pytest.mark.parametrize("timing", ["ideal", "arbitrated"])
def test_every_bus_fault_acts_is_logged_and_scored(tmp_path, timing):
    out = tmp_path / "bf.mcap"
    assert run(_scenario(tmp_path, timing=timing), out, 0).status == "completed"
    events = _events(out)
    count = Counter((m["label"] or m["kind"], m["event"]) for m in events)
    assert count[("loss", "lost")] > 5
    assert count[("corrupt", "corrupted")] > 3
    # 32 destroyed attempts take the TEC past 255; recovery after 128 x 11 bits (11.3 ms at 125 kbit/s)
    assert count[("off", "bus_off")] >= 5 and count[("bus_off", "recovered")] >= 5
    assert all(255 < m["errors"] <= 255 + 8 for m in events if m["event"] == "bus_off")
    assert count[("delay", "delayed")] == 20 and count[("spoof", "injected")] == 50
    assert count[("replay", "injected")] == 50
    metrics = compute_metrics(out)
    assert metrics["status"] == "completed"
    assert {label: f["targets"] for label, f in metrics["faults"].items()} == {
        "loss": ["SENSOR_x1"],
        "corrupt": ["SENSOR_x2"],
        "off": ["plant"],
        "delay": ["SENSOR_x1_minus_x2"],
        "spoof": ["SENSOR_x1"],
        "replay": ["SENSOR_x2"],
    }
    assert metrics["faults"]["spoof"]["onset"] == 2.0
    assert metrics["bus"]["foreign_frames"] == {"0x100": 50, "0x101": 50}
    peaks = {label: f["peak_error"] for label, f in metrics["estimators"]["kalman"]["faults"].items()}
    # the Kalman filter rides out lost frames, and a spoofed x1 too: each tick's two copies leave the
    # reading missing, not forged; the run reports those ticks as contested
    assert max(peaks["spoof"], peaks["loss"]) < 1e-4, peaks
    assert run_result_contested(out) >= 50
    with LogReader(out) as reader:
        x1 = [m["x1"] for _, t, m in reader.messages(["/can/SENSOR_x1"]) if 2.0e9 <= t < 2.5e9]
    assert x1.count(0.5) == 50


def run_result_contested(log) -> int:
    with LogReader(log) as reader:
        return int(reader.metadata()["cosim.result"].get("contested_ticks", 0))


def test_bus_faults_are_seeded(tmp_path):
    logs = []
    for name in ("a", "b"):
        out = tmp_path / f"{name}.mcap"
        run(_scenario(tmp_path), out, 0)
        logs.append(_events(out))
    assert logs[0] == logs[1]
    run(_scenario(tmp_path), tmp_path / "c.mcap", 1)
    assert _events(tmp_path / "c.mcap") != logs[0]


def test_burst_loss_has_the_mean_length_asked_for():
    model = fm.FrameLoss(channels=(), messages=("M",), probability=0.05, burst_length=4.0)
    model.reset(np.random.default_rng(0))
    lost = [model.fate("M", 0.0).lost for _ in range(200_000)]
    bursts, run_length = [], 0
    for gone in lost:
        if gone:
            run_length += 1
        elif run_length:
            bursts.append(run_length)
            run_length = 0
    assert abs(np.mean(bursts) - 4.0) < 0.3  # bursts that touch count as one: slightly longer


@pytest.mark.parametrize(
    ("table", "field"),
    [
        ('kind = "frame_loss"\nmessages = ["SENSOR_x9"]\nprobability = 0.1', "faults[0].messages"),
        ('kind = "spoofing"\nmessage = "EST_kalman_0"\nvalue = 1.0', "faults[0].message"),
        ('kind = "spoofing"\nmessage = "SENSOR_x1"\nvalue = [1.0, 2.0]', "faults[0].value"),
        ('kind = "babbling_node"\nid = 1', "faults[0]"),
        ('kind = "frame_loss"\nmessages = ["SENSOR_x1"]\nprobability = 2', "faults[0].probability"),
    ],
)
def test_bad_bus_faults_name_their_field(tmp_path, table, field):
    with pytest.raises(ScenarioError, match=field.replace("[", r"\[").replace("]", r"\]")):
        _scenario(tmp_path, faults=f"[[faults]]\n{table}\n")


def test_a_babbling_node_starves_the_sensors_on_an_arbitrated_bus(tmp_path):
    table = '[[faults]]\nname = "babbler"\nkind = "babbling_node"\nid = 0x001\nperiod = 0.0005\nstart = 1.0\nend = 2.0'
    out = tmp_path / "babble.mcap"
    assert run(_scenario(tmp_path, faults=table, timing="arbitrated"), out, 0).status == "completed"
    metrics = compute_metrics(out)
    latency = metrics["bus"]["latency"]
    assert latency["0x001"]["frames"] > 1000
    assert latency["0x102"]["dropped"] > 50  # replaced, tick after tick, while the babbler holds the wire
    assert metrics["bus"]["foreign_frames"]["0x001"] == latency["0x001"]["frames"]


def test_an_intruders_control_frames_the_wire_delivers_late_go_as_forged(monkeypatch):
    """The runner signs its own control frame of a tick (SYNC) and nothing else: a fuzzer's frames on
    the heartbeats' ids that a flood holds back until a later tick go on the channel with the MAC
    the fuzzer forged (the runner holds every sender's key: signing them let them pass)."""
    import cosim.run.session as session_module
    from cosim import api
    from cosim.run.busfaults import BusFaultStage

    window = {"start": 0.2, "end": 1.0}
    faults = [
        {"name": "flood", "kind": "babbling_node", "id": 0x001, "period": 0.0003, **window},
        {"name": "fuzz", "kind": "fuzzing", "low": 0x700, "high": 0x703, "length": 8, "period": 0.0004, **window},
    ]
    loaded = scenario.apply(api.load("masses-pid-can"), [("duration", 1.2), ("faults", faults)])
    forged: dict[int, tuple[object, bytes, int]] = {}  # id() of a fuzzer's frame -> (it, its bytes, its tick)
    sent: list[tuple[object, bytes, int]] = []
    apply, send_all, tick = BusFaultStage.apply, session_module.send_all, [0]

    def applied(self, k, frames):
        out = apply(self, k, frames)
        tick[0] = k
        for item in out.frames:
            if id(item) in out.intruders:
                forged[id(item[0])] = (item[0], bytes(item[0].data), k)
        return out

    def sending(bus, frames):
        sent.extend((frame, bytes(frame.data), tick[0]) for frame in frames)
        return send_all(bus, frames)

    monkeypatch.setattr(BusFaultStage, "apply", applied)
    monkeypatch.setattr(session_module, "send_all", sending)
    api.run(loaded, None, seed=3, in_process=True, measure=True)
    theirs = [(data, forged[id(frame)]) for frame, data, _ in sent if forged.get(id(frame), (None,))[0] is frame]
    late = [k for frame, _, k in sent if forged.get(id(frame), (None,))[0] is frame and k > forged[id(frame)][2]]
    assert len(theirs) > 100 and len(late) > 0
    assert [data for data, _ in theirs] == [original for _, (_, original, _) in theirs]
