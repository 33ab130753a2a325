"""The key-less intrusion detector ([bus] intrusion_detector = true): its checks frame by frame, and
masses-spoofing's attacks scored like a diagnosis (detection delay, false alarms per hour)."""

from __future__ import annotations

import struct

import pytest

from cosim import scenario
from cosim.analysis.metrics import compute_metrics
from cosim.log.reader import LogReader
from cosim.log.recorder import IDS, IDS_CHECKS
from cosim.run import run
from cosim.run.detector import IntrusionDetector
from cosim.scenario.overrides import apply

DT_NS = 10_000_000


class _Verdicts:
    """Stands for the recorder: keeps the verdicts."""

    def __init__(self) -> None:
        self.verdicts: dict[int, tuple[dict[str, int], list[int]]] = {}

    def ids(self, tick, t, t_ns, checks, ids):
        self.verdicts[tick] = (checks, ids)


def _codec():
    return apply(scenario.load("masses-spoofing"), {}).scenario.codec()


def test_each_check_raises_on_what_it_looks_for_and_nothing_else():
    codec = _codec()
    detector = IntrusionDetector(codec, DT_NS)

    def feed(k, t_ns, value=0.1, counter=None, name="SENSOR_x1"):
        frame, decoded = codec.encode_decoded(name, k if counter is None else counter, [value])
        detector.frame(k, t_ns, frame, decoded)
        return frame

    for k in range(5):  # genuine: once per tick, the counter one up each time
        feed(k, k * DT_NS)
        feed(k, k * DT_NS + 3000, name="SENSOR_x2")
    feed(5, 5 * DT_NS)
    feed(5, 5 * DT_NS, value=0.5)  # a second frame in the tick, same counter: period and sequence
    feed(6, 6 * DT_NS)  # the genuine sender goes on: no alarm
    feed(7, 7 * DT_NS, counter=3)  # a frame of tick 3 again, a tick later than the last: sequence only
    feed(8, 8 * DT_NS + 1000)  # the genuine one of tick 8 (tick 7's skipped): a jump is loss, no alarm
    frame, decoded = codec.encode_decoded("SENSOR_x1", 9, [0.1])
    frame.data[4:12] = struct.pack("<d", 1e6)  # outside the DBC's range (no encoder sends that)
    detector.frame(9, 9 * DT_NS, frame, codec.decode(frame))
    detector.foreign(10, frame)
    recorder = _Verdicts()
    detector.publish(recorder, 11, 0.01)  # type: ignore[arg-type]
    raised = {k: {c for c, n in checks.items() if n} for k, (checks, _) in recorder.verdicts.items()}
    assert raised == {
        **{k: set() for k in range(11)},
        5: {"period", "sequence"},
        7: {"sequence"},
        9: {"range"},
        10: {"unknown"},
    }
    assert recorder.verdicts[5][1] == [0x100] and set(recorder.verdicts[5][0]) == set(IDS_CHECKS)
    detector.publish(recorder, 11, 0.01)  # type: ignore[arg-type]
    assert len(recorder.verdicts) == 11  # each tick once


def test_a_frame_on_the_wire_outside_the_dbc_is_unknown_unless_it_is_declared_traffic():
    import can

    codec = _codec()
    flood = can.Message(arbitration_id=0x0C0, data=bytes(8), is_extended_id=False)
    for known, raised in ((frozenset(), {"unknown"}), (frozenset({0x0C0}), set())):
        detector = IntrusionDetector(codec, DT_NS, known)
        detector.frame(0, 1000, flood, None)  # a babbling node's frame, as the arbitrated wire delivers it
        recorder = _Verdicts()
        detector.publish(recorder, 1, 0.01)  # type: ignore[arg-type]
        checks, ids = recorder.verdicts[0]
        assert {c for c, n in checks.items() if n} == raised and ids == ([0x0C0] if raised else [])


@pytest.mark.slow
@pytest.mark.parametrize("timing", ["ideal", "arbitrated"])
def test_masses_spoofing_is_detected_at_once_without_false_alarms(tmp_path, timing):
    settings = {"bus.intrusion_detector": True, "bus.timing": timing}
    attacked, clean = tmp_path / "attacked.mcap", tmp_path / "clean.mcap"
    for out, more in ((attacked, {}), (clean, {"faults": []})):
        result = run(apply(scenario.load("masses-spoofing"), {**settings, **more}), out, 0, interface="virtual")
        assert result.status == "completed", result.error
    scored = compute_metrics(attacked)["bus"]["intrusion_detection"]
    report = {}
    for check, verdict in scored.items():
        report[check] = {label: fault["detection_delay"] for label, fault in verdict["faults"].items()}
        assert verdict["false_alarms"] == 0 and verdict["fault_free_time_s"] == 10.0
    # the intruder's frame follows the genuine one in the same tick, with the same tick counter
    assert report["any"] == report["period"] == report["sequence"] == {"spoof_x1": 0.0, "replay_x2": 0.0}
    # nothing out of the DBC's ranges (0.5 m is a valid x1), no frame from outside the run
    assert report["range"] == report["unknown"] == {"spoof_x1": None, "replay_x2": None}
    assert scored["any"]["missed_detections"] == 0
    # the attack-free run: a verdict every tick, none raised over its 20 s
    free = compute_metrics(clean)["bus"]["intrusion_detection"]["any"]
    assert free["false_alarms"] == 0 and free["fault_free_time_s"] == 20.0 and free["false_alarm_rate_per_hour"] == 0
    with LogReader(clean) as reader:
        verdicts = [m for _, _, m in reader.messages([IDS])]
    assert [m["tick"] for m in verdicts] == list(range(2000)) and not any(m["alarm"] for m in verdicts)
    print(timing, report)


@pytest.mark.slow
def test_an_overloaded_bus_raises_no_alarm(tmp_path):
    """Late and replaced frames on an overloaded arbitrated bus are not intrusions."""
    out = tmp_path / "overload.mcap"
    loaded = apply(scenario.load("masses-bus-overload"), {"bus.intrusion_detector": True, "faults": []})
    assert run(loaded, out, 0, interface="virtual").status == "completed"
    metrics = compute_metrics(out)
    assert metrics["bus"]["latency"]["0x102"]["dropped"] > 1000  # the overload is there: replaced frames
    verdict = metrics["bus"]["intrusion_detection"]["any"]
    assert verdict["false_alarms"] == 0 and verdict["fault_free_time_s"] == 30.0
    # the same flood, not declared but a babbling-node fault: unknown to the detector from its first frame
    babbling = {"name": "babbling", "kind": "babbling_node", "id": 0x0C0, "period": 0.0011, "start": 10.0, "end": 20.0}
    loaded = apply(
        scenario.load("masses-bus-overload"), {"bus.intrusion_detector": True, "bus.traffic": [], "faults": [babbling]}
    )
    assert run(loaded, out, 0, interface="virtual").status == "completed"
    scored = compute_metrics(out)["bus"]["intrusion_detection"]
    assert scored["unknown"]["faults"]["babbling"]["detection_delay"] == 0.0 and scored["any"]["false_alarms"] == 0


def test_without_the_detector_the_log_has_no_verdicts(tmp_path):
    out = tmp_path / "plain.mcap"
    loaded = apply(scenario.load("masses-spoofing"), {"duration": 1.0})
    assert run(loaded, out, 0, interface="virtual").status == "completed"
    metrics = compute_metrics(out)
    assert IDS not in metrics["channels"] and "intrusion_detection" not in metrics["bus"]


@pytest.mark.parametrize("fd", [False, True])
def test_the_next_counter_raises_neither_sequence_check_whenever_it_comes(fd):
    """``frame_checks`` skips ``sequence_alarms`` for a frame whose counter follows its id's last:
    the rule itself raises neither the period nor the sequence check for it, however soon it comes,
    across the counter's wrap too; any other step is left to the rule."""
    import random

    from cosim.run.detector import frame_checks, sequence_alarms

    codec = scenario.load("masses-pid-can" if not fd else "masses-faults-fd").scenario.codec()
    modulus, dt_ns = codec.tick_modulus, 10_000_000
    rng = random.Random(fd)
    for _ in range(3000):
        previous = rng.choice([0, modulus - 1, rng.randrange(modulus)])
        elapsed = rng.choice([0, 1, dt_ns // 2 - 1, dt_ns // 2, rng.randrange(3 * dt_ns)])
        assert sequence_alarms(elapsed, (previous + 1) % modulus, previous, dt_ns, codec) == (False, False)
        counter = rng.choice([previous, (previous + 1) % modulus, (previous - 1) % modulus, rng.randrange(modulus)])
        period, sequence = sequence_alarms(elapsed, counter, previous, dt_ns, codec)
        decoded = codec.decode(codec.encode(codec.sensor("x1").name, counter, [0.0]))
        raised, in_sequence = frame_checks((1_000, previous), 1_000 + elapsed, counter, decoded, dt_ns, codec)
        assert raised == [check for check, on in (("period", period), ("sequence", sequence)) if on]
        assert in_sequence is not bool(sequence)
