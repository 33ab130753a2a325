"""Nodes see only frames: tick assembly from SYNC, and an estimator node's answers."""

from __future__ import annotations

import can
import numpy as np
import pytest

import mjcf
from cosim.codec import Codec
from cosim.node import EstimatorNode, NodeDriver, TickAssembler

INFO = mjcf.get("masses")


def codec(fd=False) -> Codec:
    return Codec(INFO.sensors[:3], INFO.actuators, {"est": INFO.states}, fd=fd)


def tick_frames(c: Codec, k: int, readings: dict[str, float], force: float) -> list[can.Message]:
    frames = [c.encode(f"SENSOR_{n}", k, [v]) for n, v in readings.items()]
    frames.append(c.encode("COMMAND_force", k, [force]))
    return [c.sync(k, len(frames)), *frames]


def test_a_tick_completes_when_its_announced_frames_arrived():
    c = codec()
    assembler = TickAssembler(c)
    frames = tick_frames(c, 3, {"x1": 0.1, "x2": 0.2, "x1_minus_x2": -0.1}, 1.5)
    done = [t for f in frames for t in assembler.push(f)]
    assert len(done) == 1
    (tick,) = done
    assert tick.tick == 3 and tick.complete and tick.commands == {"force": 1.5}
    assert tick.sensors == pytest.approx({"x1": 0.1, "x2": 0.2, "x1_minus_x2": -0.1}, abs=1e-12)
    assert assembler.lost == 0


def test_a_dropped_sensor_frame_is_not_awaited():
    c = codec()
    assembler = TickAssembler(c)
    frames = tick_frames(c, 0, {"x1": 0.1, "x2": 0.2}, 0.0)  # the range sensor's frame was not sent
    (tick,) = [t for f in frames for t in assembler.push(f)]
    assert "x1_minus_x2" not in tick.sensors and assembler.lost == 0


def test_frames_lost_in_transport_are_counted_at_the_next_sync():
    c = codec()
    assembler = TickAssembler(c)
    frames = tick_frames(c, 0, {"x1": 0.1, "x2": 0.2, "x1_minus_x2": -0.1}, 0.0)
    assert [t for f in frames[:-2] for t in assembler.push(f)] == []  # two frames never arrive
    incomplete, = assembler.push(c.sync(1, 0))[:1]
    assert not incomplete.complete and assembler.lost == 2


def test_a_late_frame_of_an_earlier_tick_is_counted_not_used():
    c = codec()
    assembler = TickAssembler(c)
    assembler.push(c.sync(5, 1))
    assert assembler.push(c.encode("SENSOR_x1", 4, [0.3])) == []
    assert assembler.lost == 1


def test_frames_outside_the_database_are_ignored():
    c = codec()
    assembler = TickAssembler(c)
    assert assembler.push(can.Message(arbitration_id=0x7E0, data=b"\x01", is_extended_id=False)) == []


def test_estimator_node_answers_each_tick_over_a_bus():
    from estimators import create
    from cosim.plant import Plant

    for fd in (False, True):
        c = codec(fd)
        model = Plant(INFO, 0.01, ["x1", "x2", "x1_minus_x2"]).linearize()
        node = EstimatorNode("est", create("pseudoinverse", model, {"x0": (0.1, 0.0, 0.0, 0.0)}), c,
                             ("x1", "x2", "x1_minus_x2"), ("force",))
        channel = f"node-test-{fd}"
        with can.Bus(interface="virtual", channel=channel) as runner, can.Bus(interface="virtual", channel=channel) as bus:
            driver = NodeDriver(node, bus)
            for frame in tick_frames(c, 0, {"x1": 0.1, "x2": 0.0, "x1_minus_x2": 0.1}, 0.0):
                runner.send(frame)
            assert driver.service() == 1
            replies = []
            while (reply := runner.recv(0.0)) is not None:
                replies.append(c.decode(reply))
        assert [r.spec.sender for r in replies] == ["est"] * len(c.messages(sender="est"))
        values = {k: v for r in replies for k, v in r.values.items()}
        np.testing.assert_allclose([values[f"xhat_{s}"] for s in model.states], [0.1, 0.0, 0.0, 0.0], atol=1e-6)
