"""The log's topics (``cosim.log.topics``): each record's schema, its message as written, and the
record read back from a real MCAP file; a payload built on the fast path holds to its record."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from cosim import scenario
from cosim.bus.codec import Codec
from cosim.log import topics
from cosim.log.reader import LogReader
from cosim.log.recorder import RunRecorder
from cosim.log.writer import McapLog

RECORDS: list[type[topics.Record]] = [
    topics.CanFrame,
    topics.TruthState,
    topics.TruthSensors,
    topics.TruthInputs,
    topics.TruthFaults,
    topics.DeadlineMiss,
    topics.Foreign,
    topics.Event,
    topics.BusFaultEvent,
    topics.WirePassage,
    topics.SecurityRejection,
    topics.IntrusionVerdict,
]
PLANT = topics.PlantNames(
    ("x1", "v1"),
    ("y1", "y2"),
    ("force",),
    ("wind",),
    {"states": {"x1": "m", "v1": "m/s"}, "sensors": {"y1": "m"}, "actuators": {"force": "N"}},
)


@pytest.fixture(scope="module")
def codec() -> Codec:
    return scenario.load().scenario.codec()


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, codec):
    """A log with one message on every topic, written by the recorder: (topic, JSON) in file order."""
    path = tmp_path_factory.mktemp("topics") / "all.mcap"
    with McapLog(path) as log:
        recorder = RunRecorder(
            log,
            codec,
            states=PLANT.states,
            sensors=PLANT.sensors,
            actuators=PLANT.actuators,
            units=PLANT.units,
            disturbances=PLANT.disturbances,
        )
        frame, decoded = codec.encode_decoded("SENSOR_x1", 70_000, (0.25,))
        recorder.frame(70_003, 700.03, 700_030_000_000, frame, decoded)
        recorder.truth(
            3,
            0.03,
            30_000_000,
            x=np.array([1.0, 2.0]),
            y_true=np.array([1.5, 2.5]),
            noise=np.array([0.1, 0.2]),
            fault=np.array([0.0, 1.0]),
            measured=np.array([1.6, np.nan]),
            active=("f1",),
            u_cmd=np.array([3.0]),
            u_eff=np.array([1.5]),
            delta=np.array([0.5]),
            disturbance=np.array([0.7]),
        )
        recorder.deadline_miss(3, 0.03, 30_000_000, "kalman", 2)
        foreign = {"kind": "frame", "reason": "not sent by its owner", "source": "10.0.0.2", "id": 0x100, "length": 8}
        recorder.foreign(30_000_000, topics.Foreign(tick=3, t=0.03, **foreign, data="0102", count=4))
        recorder.event(3, 0.03, 30_000_000, "frames_lost", "SENSOR_x1", "warning", 5)
        bus_off = {"label": "b", "kind": "bus_off", "message": "plant", "event": "bus_off", "errors": 256}
        recorder.bus_fault(3, 0.03, 30_000_000, bus_off)
        recorder.wire(3, 31_000_000, 0x101, "SENSOR_x2", "plant", (30_000_000, 30_500_000, 31_000_000), True, 135, None)
        recorder.security(3, 0.03, 30_000_000, 0x100, "SENSOR_x1", "plant", "replayed", 41, b"\xab")
        recorder.ids(3, 0.03, 30_000_000, {"period": 0, "sequence": 1, "range": 0, "unknown": 2}, [0x100, 0x7FF])
    with LogReader(path) as reader:
        return [(topic, time, message) for topic, time, message in reader.messages()], reader.schemas()


def test_every_message_is_written_as_its_record_says(recorded):
    messages, _ = recorded
    written = {topic: message for topic, _, message in messages}
    assert written["/can/frames"] == {
        "tick": 70_003,
        "t": 700.03,
        "seq": 0,
        "id": 0x100,
        "extended": False,
        "fd": False,
        "brs": False,
        "dlc": 5,  # a classic frame: the 16-bit tick and x1
        "length": 5,
        "data": written["/can/frames"]["data"],
        "sender": "plant",
        "message": "SENSOR_x1",
    }
    assert written["/can/SENSOR_x1"] == {"tick": 70_000 % 65_536, "x1": pytest.approx(0.25, abs=1e-3)}
    assert written["/truth/state"] == {"tick": 3, "t": 0.03, "x1": 1.0, "v1": 2.0}
    assert written["/truth/inputs"] == {
        "tick": 3,
        "t": 0.03,
        "commanded": {"force": 3.0},
        "effective": {"force": 1.5},
        "disturbance": {"wind": 0.7},
    }
    assert written["/truth/faults"] == {
        "tick": 3,
        "t": 0.03,
        "noise": {"y1": 0.1, "y2": 0.2},
        "fault": {"y1": 0.0, "y2": 1.0},
        "measured": {"y1": 1.6, "y2": None},
        "dropped": ["y2"],
        "effectiveness": {"force": 0.5},
        "active": ["f1"],
    }
    assert written["/cosim/events"] == {
        "tick": 3,
        "t": 0.03,
        "level": "warning",
        "event": "frames_lost",
        "detail": "SENSOR_x1",
        "count": 5,
    }
    assert written["/cosim/wire"] == {
        "tick": 3,
        "t": 0.031,
        "id": 0x101,
        "message": "SENSOR_x2",
        "sender": "plant",
        "queued": 0.03,
        "start": 0.0305,
        "delivered": 0.031,
        "latency": pytest.approx(0.001),
        "late": True,
        "bits": 135,
        "dropped": None,
    }
    assert written["/cosim/ids"] == {
        "tick": 3,
        "t": 0.03,
        "alarm": True,
        "period": 0,
        "sequence": 1,
        "range": 0,
        "unknown": 2,
        "ids": [0x100, 0x7FF],
    }


def test_each_message_has_its_records_fields_in_order_and_its_schemas(recorded):
    messages, schemas = recorded
    written = {topic: message for topic, _, message in messages}
    for record in RECORDS:
        message = written[record.TOPIC]
        properties = list(schemas[record.TOPIC]["properties"])
        assert list(message) == properties, record.TOPIC
        if record not in (topics.TruthState, topics.TruthSensors):  # their fields are the plant's names
            assert list(message) == list(topics.field_names(record)), record.TOPIC
        assert schemas[record.TOPIC]["title"] == record.TITLE and schemas[record.TOPIC]["required"] == properties


def test_records_read_back_what_was_written(recorded):
    messages, _ = recorded
    written = {topic: (time, message) for topic, time, message in messages}
    frame = topics.CanFrame.read(written["/can/frames"][1])
    assert (frame.id, frame.message, frame.sender, frame.tick) == (0x100, "SENSOR_x1", "plant", 70_003)
    assert frame.can_message().data == bytes.fromhex(frame.data)
    signals = topics.Signals.read(written["/can/SENSOR_x1"][1], logged_tick=70_003)
    assert signals.tick == 70_000 and set(signals.values) == {"x1"}
    state = topics.TruthState.read(written["/truth/state"][1])
    assert state.values == {"x1": 1.0, "v1": 2.0} and list(state.vector(["v1", "x1"])) == [2.0, 1.0]
    assert topics.TruthSensors.read(written["/truth/sensors"][1]).values == {"y1": 1.5, "y2": 2.5}
    faults = topics.TruthFaults.read(written["/truth/faults"][1])
    assert faults.active == ["f1"] and faults.dropped == ["y2"] and faults.effectiveness == {"force": 0.5}
    assert topics.TruthInputs.read(written["/truth/inputs"][1]).effective == {"force": 1.5}
    assert topics.DeadlineMiss.read(written["/cosim/deadline_misses"][1]).node == "kalman"
    foreign = topics.Foreign.read(written["/cosim/foreign"][1])
    assert (foreign.kind, foreign.id, foreign.count, foreign.data) == ("frame", 0x100, 4, "0102")
    assert topics.BusFaultEvent.read(written["/truth/bus_faults"][1]).errors == 256
    assert topics.WirePassage.read(written["/cosim/wire"][1]).late is True
    assert topics.SecurityRejection.read(written["/cosim/security"][1]).freshness == 41
    verdict = topics.IntrusionVerdict.read(written["/cosim/ids"][1])
    assert verdict.checks() == {"period": 0, "sequence": 1, "range": 0, "unknown": 2}
    assert tuple(verdict.checks()) == topics.IDS_CHECKS


def test_reading_is_lenient_with_fields_a_log_lacks_or_adds():
    event = topics.Event.read({"tick": 1, "t": 0.1, "level": "info"})
    assert event == topics.Event(tick=1, t=0.1, level="info", event="", count=1)
    foreign = {"tick": 1, "t": 0.1, "kind": "datagram", "reason": "r", "source": "s", "length": 3, "data": "", "new": 1}
    assert topics.Foreign.read(foreign).count == 1
    with pytest.raises(TypeError):
        topics.Event.read({"tock": 1})
    with pytest.raises(KeyError):
        topics.TruthState.read({"tock": 1})


def test_a_message_path_names_a_field_of_its_record():
    assert topics.path(topics.TruthFaults, "fault", "y1") == "/truth/faults.fault.y1"
    with pytest.raises(KeyError, match="no field 'faults'"):
        topics.path(topics.TruthFaults, "faults")


def test_the_truth_schemas_need_the_plants_names():
    with pytest.raises(TypeError, match="needs the run's names"):
        topics.TruthFaults.schema()
    schema = topics.TruthFaults.schema(PLANT)
    assert schema["properties"]["measured"]["properties"]["y1"] == {"type": ["number", "null"], "description": "y1 [m]"}
    assert json.loads(json.dumps(topics.Event.schema()))["properties"]["level"] == {
        "type": "string",
        "enum": ["info", "warning", "error"],
    }


def test_every_record_is_a_slotted_dataclass_of_this_module():
    for record in RECORDS:
        assert dataclasses.is_dataclass(record) and issubclass(record, topics.Record)
        assert all("__slots__" in vars(base) for base in record.__mro__[:-1]), record  # no __dict__ per message


def test_read_back_is_the_round_trip_through_the_log_bytes() -> None:
    """A scorer fed as the run writes reads what a reader of the file reads: ``read_back`` gives
    ``orjson.loads(dumps(payload))`` (same types, same bits: -0.0, subnormals, the largest doubles,
    64-bit integers), and is a copy."""
    import math
    import struct

    import orjson

    from cosim.log.writer import dumps, read_back

    rng = np.random.default_rng(7)
    doubles = [struct.unpack("<d", rng.bytes(8))[0] for _ in range(2000)]  # every exponent, NaN and inf among them
    special = [0.0, -0.0, 5e-324, -5e-324, 1.7976931348623157e308, math.nan, math.inf, -math.inf, 0.1, 1 / 3]
    integers = [0, -1, 2**53 + 1, 2**63 - 1, -(2**63), 2**64 - 1]
    payloads = [{"tick": i, "x": v, "y": -v} for i, v in enumerate(doubles + special)]
    payloads += [{"tick": n, "flag": True, "none": None} for n in integers]
    payloads += [{"a": [1.0, 2.0]}, {"a": {"b": math.nan}}, {"a": "text"}, {"a": np.float64(0.5)}, {}]
    assert any(not math.isfinite(v) for v in doubles)
    for payload in payloads:
        expected, got = orjson.loads(dumps(payload)), read_back(payload)
        assert got is not payload
        assert list(got) == list(expected)
        for key, value in expected.items():
            assert type(got[key]) is type(value), (payload, key)
            if isinstance(value, float):
                assert struct.pack("<d", got[key]) == struct.pack("<d", value), (payload, key)
            else:
                assert got[key] == value, (payload, key)
    for unwritable in ({"n": 2**64}, {"n": -(2**63) - 1}, {1: 1.0}, {"k\ud800": 1.0}):
        with pytest.raises((orjson.JSONEncodeError, TypeError)):
            read_back(unwritable)  # as writing it would fail
    assert read_back({"é": 0.5}) == {"é": 0.5}
