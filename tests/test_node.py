"""Nodes and clients see only frames: tick assembly, heartbeats, node specs, the client library."""

from __future__ import annotations

import json
import math

import can
import numpy as np
import pytest

import mjcf
from cosim.bus.client import Client, TickAssembler
from cosim.bus.codec import BOOTUP, NMT_STOP, OPERATIONAL, RUNNER, STOPPED, Codec
from cosim.bus.control_frames import ControlAuth, control_keys
from cosim.bus.signals import Channel
from cosim.bus.transport import BusConfig
from cosim.errors import CosimError
from cosim.plant.physics import Plant
from cosim.run.node import EstimatorNode, NodeSpec
from estimators import LinearModel

INFO = mjcf.get("masses")
SENSORS = ("x1", "x2", "x1_minus_x2")
SECRET = bytes(range(32))


def codec(fd=False) -> Codec:
    return Codec(
        INFO.sensors[:3],
        INFO.actuators,
        {"est": INFO.states},
        clients={"avg": [Channel("z", "m", "", -8, 8, 1e-6)]},
        fd=fd,
    )


def tick_frames(c: Codec, k: int, readings: dict[str, float], force: float) -> list[can.Message]:
    frames = [c.encode(f"SENSOR_{n}", k, [v]) for n, v in readings.items()]
    frames.append(c.encode("COMMAND_force", k, [force]))
    return [c.sync(k, len(frames)), *frames]


def push_all(assembler: TickAssembler, frames):
    return [t for f in frames for t in assembler.push(assembler.codec.decode(f))]


def test_a_tick_completes_when_its_announced_frames_arrived():
    c = codec()
    assembler = TickAssembler(c, sample_time=0.01)
    (tick,) = push_all(assembler, tick_frames(c, 3, {"x1": 0.1, "x2": 0.2, "x1_minus_x2": -0.1}, 1.5))
    assert tick.tick == 3 and tick.complete and tick.commands == {"force": 1.5} and tick.t == pytest.approx(0.03)
    assert tick.sensors == pytest.approx({"x1": 0.1, "x2": 0.2, "x1_minus_x2": -0.1}, abs=1e-12)
    assert assembler.lost == 0


def test_a_dropped_sensor_frame_is_not_awaited():
    c = codec()
    assembler = TickAssembler(c)
    (tick,) = push_all(
        assembler, tick_frames(c, 0, {"x1": 0.1, "x2": 0.2}, 0.0)
    )  # the range sensor's frame was not sent
    assert "x1_minus_x2" not in tick.sensors and assembler.lost == 0


def test_frames_lost_in_transport_are_counted_at_the_next_sync():
    c = codec()
    assembler = TickAssembler(c)
    frames = tick_frames(c, 0, {"x1": 0.1, "x2": 0.2, "x1_minus_x2": -0.1}, 0.0)
    assert push_all(assembler, frames[:-2]) == []  # two frames never arrive
    incomplete = push_all(assembler, [c.sync(1, 0)])[0]
    assert not incomplete.complete and assembler.lost == 2


def test_a_late_frame_of_an_earlier_tick_is_counted_not_used():
    c = codec()
    assembler = TickAssembler(c)
    push_all(assembler, [c.sync(5, 1)])
    assert push_all(assembler, [c.encode("SENSOR_x1", 4, [0.3])]) == []
    assert assembler.lost == 1


def test_a_second_copy_of_a_message_in_a_tick_leaves_neither_trusted():
    """Someone else sends SENSOR_x1 and COMMAND_force too (spoofing, without authentication): the
    reading becomes missing (NaN), the command is not taken (the node holds its previous one), and
    the copies do not count towards the frames SYNC announced. (A copy that comes after its tick is
    complete is too late to be seen: the runner's contested ticks say so.)"""
    c = codec()
    assembler = TickAssembler(c)
    frames = tick_frames(c, 2, {"x1": 0.1, "x2": 0.2, "x1_minus_x2": -0.1}, 1.5)
    forged = [c.encode("SENSOR_x1", 2, [0.5]), c.encode("COMMAND_force", 2, [-3.0])]
    sync, x1, x2, x1_minus_x2, force = frames
    (tick,) = push_all(assembler, [sync, x1, forged[0], force, forged[1], x2, x1_minus_x2])
    assert tick.complete and tick.received == 4 and assembler.contested == 2 and assembler.lost == 0
    assert math.isnan(tick.sensors["x1"]) and tick.sensors["x2"] == pytest.approx(0.2)
    assert "force" not in tick.commands


def node_spec(fd: bool, channel: str) -> NodeSpec:
    model = Plant(INFO, 0.01, SENSORS).linearize()
    return NodeSpec(
        "est",
        "pseudoinverse",
        {"x0": [0.1, 0.0, 0.0, 0.0]},
        model,
        codec(fd).dbc,
        BusConfig("virtual", channel, fd=fd),
        0.01,
        control_keys=control_keys(SECRET, ["est", RUNNER]),
    )


def signed(auth: ControlAuth, k: int, frames: list[can.Message]) -> list[can.Message]:
    for frame in frames:
        auth.sign(frame, k)
    return frames


def test_node_spec_round_trips_through_json_exactly():
    spec = node_spec(False, "x")
    again = NodeSpec.from_json(spec.to_json())
    assert again.name == spec.name and again.params == spec.params and again.bus == spec.bus and again.dbc == spec.dbc
    for key in ("A", "B", "C", "D", "x_op", "u_op", "y_op"):
        assert np.array_equal(getattr(again.model, key), getattr(spec.model, key))
    assert again.model.states == spec.model.states and again.model.dt == spec.model.dt


@pytest.mark.parametrize("fd", [False, True])
def test_estimator_node_answers_each_tick_then_closes_it_with_a_heartbeat(fd):
    spec = node_spec(fd, f"node-test-{fd}")
    c = Codec.from_dbc(spec.dbc)
    with (
        can.Bus(interface="cosim_virtual", channel=spec.bus.channel) as runner,
        can.Bus(interface="cosim_virtual", channel=spec.bus.channel) as bus,
    ):
        auth = ControlAuth.from_secret(c, SECRET, [RUNNER, "est"])
        node = EstimatorNode(spec, bus)
        node.client.join()
        boot_frame = runner.recv(0.0)
        boot = c.decode(boot_frame)
        assert boot.spec.name == "HEARTBEAT_est" and boot.values["state"] == BOOTUP
        assert auth.verify(boot_frame, 0) is None  # signed with the node's control key
        for frame in signed(auth, 0, tick_frames(c, 0, {"x1": 0.1, "x2": 0.0, "x1_minus_x2": 0.1}, 0.0)):
            runner.send(frame)
        assert node.service() == 1
        replies = []
        while (reply := runner.recv(0.0)) is not None:
            assert auth.verify(reply, 0) is None
            replies.append(c.decode(reply))
        runner.send(c.nmt(NMT_STOP))  # unsigned: anyone's
        node.service()
        assert not node.client.stopped and sum(node.client.rejections.values()) == 1
        runner.send(signed(auth, 0, [c.nmt(NMT_STOP)])[0])
        node.service()
        assert node.client.stopped
    *estimates, heartbeat = replies
    assert [r.spec.name for r in estimates] == [m.name for m in c.data_messages("est")]
    assert heartbeat.spec.name == "HEARTBEAT_est" and heartbeat.tick == 0
    assert heartbeat.values == {"state": OPERATIONAL, "frames": len(estimates), "lost": 0}
    values = {k: v for r in estimates for k, v in r.values.items()}
    np.testing.assert_allclose([values[f"xhat_{s}"] for s in spec.model.states], [0.1, 0.0, 0.0, 0.0], atol=1e-6)


def test_a_client_publishes_its_declared_messages_and_heartbeats():
    c = codec()
    with (
        can.Bus(interface="cosim_virtual", channel="client-test") as runner,
        can.Bus(interface="cosim_virtual", channel="client-test") as bus,
    ):
        client = Client("avg", c, bus)
        assert client.declared and client.lockstep
        client.join()
        for frame in tick_frames(c, 7, {"x1": 0.3, "x2": 0.1, "x1_minus_x2": 0.2}, 0.0):
            runner.send(frame)
        ticks = []
        while (frame := bus.recv(0.0)) is not None:
            ticks += client.feed(frame)
        (tick,) = ticks
        client.publish(tick, {"z": (tick.sensors["x1"] + tick.sensors["x2"] + tick.sensors["x1_minus_x2"]) / 3})
        client.done(tick)
        with pytest.raises(CosimError, match="publish: no value for z"):
            client.publish(tick, {"y": 1.0})
        client.close()
        received = [c.decode(f) for f in iter(lambda: runner.recv(0.0), None)]
    assert [(d.spec.name, d.values.get("state")) for d in received] == [
        ("HEARTBEAT_avg", BOOTUP),
        ("CLIENT_avg", None),
        ("HEARTBEAT_avg", OPERATIONAL),
        ("HEARTBEAT_avg", STOPPED),
    ]
    assert received[1].tick == 7 and received[1].values["z"] == pytest.approx(0.2, abs=1e-6)
    assert received[2].tick == 7 and received[2].values["frames"] == 1


def test_an_undeclared_client_only_listens():
    c = codec()
    with can.Bus(interface="cosim_virtual", channel="passive") as bus:
        client = Client("watcher", c, bus)
        assert not client.declared and not client.lockstep
        client.join()  # no heartbeat: the runner does not wait for it
        with pytest.raises(CosimError, match="has no messages in this run's DBC"):
            client.publish(0, {})


def test_frames_outside_the_database_are_ignored():
    c = codec()
    with can.Bus(interface="cosim_virtual", channel="foreign") as bus:
        client = Client(None, c, bus)
        assert client.feed(can.Message(arbitration_id=0x7E0, data=b"\x01", is_extended_id=False)) == []
        assert client.feed(can.Message(arbitration_id=0x100, data=b"\x01", is_extended_id=False)) == []  # too short


def test_a_model_computes_the_same_bits_in_a_node_as_in_the_runner():
    """A linearization may hand back Fortran-ordered matrices, which BLAS multiplies by another
    path (rounding differently); the model a node reads from JSON is C-ordered. LinearModel stores
    C order, so both compute bit for bit the same (replay relies on it)."""
    rng = np.random.default_rng(0)
    A, B = np.asfortranarray(rng.normal(size=(3, 3))), np.asfortranarray(rng.normal(size=(3, 2)))
    model = LinearModel(A, B, np.eye(3), np.zeros((3, 2)), 1.0, ("a", "b", "c"), ("u", "v"), ("y1", "y2", "y3"))
    assert model.A.flags["C_CONTIGUOUS"] and model.B.flags["C_CONTIGUOUS"]
    shipped = LinearModel.from_dict(json.loads(json.dumps(model.to_dict())))
    for _ in range(100):
        u, x = rng.normal(size=2) * 40, rng.normal(size=3)
        assert (model.B @ u).tolist() == (shipped.B @ u).tolist() and (model.A @ x).tolist() == (shipped.A @ x).tolist()


def test_a_node_built_from_its_spec_steps_bit_for_bit_as_the_runner_s_estimator():
    """The node's spec carries the runner's design (node_params: e.g. the placed gain, so that the
    node does not import scipy.signal to place it again); the node's estimator is the same to the bit."""
    from cosim import scenario
    from cosim.run.plan import RunPlan
    from estimators import create

    plan = RunPlan.build(scenario.load("masses-bias"))
    rng = np.random.default_rng(0)
    for name, runner_side in plan.estimators.items():
        spec = NodeSpec.from_json(plan.node_spec(name, BusConfig("virtual", "x")).to_json())
        node_side = create(spec.kind, spec.model, spec.params, spec.sample_time)
        for _ in range(50):
            y, u = rng.normal(size=spec.model.p), rng.normal(size=spec.model.m)
            a, b = runner_side.step(y, u), node_side.step(y, u)
            assert np.array_equal(a.x, b.x, equal_nan=True) and repr(a.diagnostics) == repr(b.diagnostics), name
