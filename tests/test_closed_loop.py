"""Closed loop over the bus: a controller node commands the actuators from the sensor frames,
estimators read its commands, and it reads a diagnosis node's report one tick late."""

from __future__ import annotations

import can
import numpy as np
import pytest

from cosim import scenario
from cosim.bus.client import TickAssembler
from cosim.bus.codec import CONTROLLER, OPERATIONAL, Codec
from cosim.bus.signals import Channel
from cosim.errors import ScenarioError
from cosim.log.reader import LogReader
from cosim.run import run
from estimators import LinearModel, ParameterError
from estimators.controller import PidController, create
from tests.frame_digests import unsigned
from tests.snippets import masses_pid

PID_SCENARIO = masses_pid()


def load(tmp_path, text=PID_SCENARIO, name="pid.toml"):
    path = tmp_path / name
    path.write_text(text)
    return scenario.load(path)


def topics(path, wanted):
    out: dict[str, list] = {}
    with LogReader(path) as reader:
        for topic, _, message in reader.messages(wanted):
            if topic == "/can/frames":  # each run signs its control frames with its own key
                message = {**message, "data": unsigned(message["id"], message["data"])}
            out.setdefault(topic, []).append(message)
    return out


# -- the PID law --------------------------------------------------------------------------------


def integrator_model(dt=0.1) -> LinearModel:
    """x⁺ = x + dt u, y = x: one loop whose closed-loop behaviour is known in closed form."""
    return LinearModel(np.eye(1), dt * np.eye(1), np.eye(1), np.zeros((1, 1)), dt, ("x",), ("u",), ("y",))


def test_pid_is_the_textbook_law_with_derivative_on_the_measurement():
    pid = create(
        "pid",
        integrator_model(),
        {"outputs": ["y"], "inputs": ["u"], "setpoint": [1.0], "kp": [2.0], "ki": [0.5], "kd": [0.3]},
        0.1,
    )
    first = pid.step(np.array([0.0]), 0.0, {})
    assert first.u[0] == pytest.approx(2.0 * 1.0 + 0.5 * 0.1 * 1.0)  # no derivative kick at the first sample
    second = pid.step(np.array([0.2]), 0.1, {})
    e = 0.8
    assert second.u[0] == pytest.approx(2.0 * e + 0.5 * (0.1 + 0.1 * e) - 0.3 * 0.2 / 0.1)
    assert second.diagnostics["e_y"] == pytest.approx(e)


def test_pid_regulates_an_integrator_and_holds_a_missing_reading():
    model = integrator_model()
    pid = create("pid", model, {"outputs": ["y"], "inputs": ["u"], "setpoint": [1.0], "kp": [3.0], "ki": [0.5]}, 0.1)
    x = np.zeros(1)
    for k in range(2000):  # the slowest closed-loop pole is about 1 − τ k_i / k_p = 0.983
        u = pid.step(model.C @ x, 0.1 * k, {}).u
        x = model.A @ x + model.B @ u
    assert x[0] == pytest.approx(1.0, abs=1e-6)
    held = pid.step(np.array([np.nan]), 200.0, {}).u
    assert np.isfinite(held).all() and held == pytest.approx(pid.step(np.array([np.nan]), 200.1, {}).u)


def test_pid_anti_windup_stops_integrating_while_saturated():
    pid = create(
        "pid",
        integrator_model(),
        {
            "outputs": ["y"],
            "inputs": ["u"],
            "setpoint": [10.0],
            "kp": [1.0],
            "ki": [1.0],
            "upper": [0.5],
            "lower": [-0.5],
        },
        0.1,
    )
    for k in range(100):
        assert pid.step(np.array([0.0]), 0.1 * k, {}).u[0] == 0.5
    assert pid.integral[0] == pytest.approx(0.0)  # never advanced: the error pushed further out each time


@pytest.mark.parametrize(
    "params, field",
    [
        ({"outputs": ["nope"], "inputs": ["u"]}, "outputs"),
        ({"outputs": ["y"], "inputs": ["u", "u"]}, "outputs"),
        ({"outputs": ["y"], "inputs": ["u"], "kp": [1.0, 2.0, 3.0]}, "kp"),
        ({"outputs": ["y"], "inputs": ["u"], "lower": [1.0], "upper": [0.0]}, "lower"),
        ({"outputs": "y", "inputs": ["u"]}, "outputs"),
    ],
)
def test_bad_pid_parameters_name_the_field(params, field):
    with pytest.raises(ParameterError) as error:
        PidController.from_params(integrator_model(), params, 0.1)
    assert error.value.parameter == field


# -- the protocol -------------------------------------------------------------------------------


def small_codec() -> Codec:
    sensors = [Channel("y", "m", "", -10, 10, 1e-3)]
    actuators = [Channel("u", "N", "", -10, 10, 1e-3)]
    states = [Channel("x", "m", "", -10, 10, 1e-3)]
    diagnostics = {"diag": [Channel("fault_mask", "", "", -100, 100, 1.0)]}
    return Codec(sensors, actuators, {"diag": states}, diagnostics=diagnostics, controller=[], fd=True)


def test_upstream_frames_complete_a_tick_only_once_the_node_closed_the_tick_it_is_read_at():
    codec = small_codec()
    decode = codec.decode
    estimator = TickAssembler(codec, 0.1, upstream={CONTROLLER: 0})
    controller = TickAssembler(codec, 0.1, upstream={"diag": 1})
    sync0, sensor0 = codec.sync(0, 1), codec.encode("SENSOR_y", 0, [1.0])
    # The controller's tick 0 needs nothing upstream (there is no tick -1).
    assert controller.push(decode(sync0)) == []
    [tick] = controller.push(decode(sensor0))
    assert tick.sensors == {"y": 1.0} and tick.upstream == {"diag": {}}
    # The estimator's tick 0 waits for the controller's commands of tick 0 and the heartbeat announcing them.
    assert estimator.push(decode(sync0)) == [] and estimator.push(decode(sensor0)) == []
    assert estimator.push(decode(codec.encode("COMMAND_u", 0, [2.5]))) == []
    [tick] = estimator.push(decode(codec.heartbeat(CONTROLLER, OPERATIONAL, 0, frames=1)))
    assert tick.commands == {"u": 2.5} and tick.sensors == {"y": 1.0}
    # The diagnosis report of tick 0 reaches the controller at tick 1, and not before it closed tick 0.
    controller.push(decode(codec.encode("EST_diag", 0, [0.0, 3.0])))
    assert controller.push(decode(codec.sync(1, 1))) == []
    assert controller.push(decode(codec.encode("SENSOR_y", 1, [1.5]))) == []
    [tick] = controller.push(decode(codec.heartbeat("diag", OPERATIONAL, 0, frames=1)))
    assert tick.tick == 1 and tick.upstream == {"diag": {"xhat_x": 0.0, "fault_mask": 3.0}}


def test_the_controller_is_a_node_with_commands_status_and_heartbeat_in_the_dbc():
    codec = Codec.from_dbc(small_codec().dbc)
    assert CONTROLLER in codec.node_ids
    assert [m.name for m in codec.data_messages(CONTROLLER)] == ["COMMAND_u"]
    loaded = scenario.parse(PID_SCENARIO)
    names = [m.name for m in Codec.from_dbc(loaded.codec().dbc).data_messages(CONTROLLER)]
    assert names[0] == "COMMAND_force" and all(n.startswith("CONTROL_STATUS") for n in names[1:])


# -- runs ---------------------------------------------------------------------------------------


@pytest.mark.slow
def test_a_closed_loop_run_over_processes_matches_the_in_process_bus_and_regulates(tmp_path):
    loaded = load(tmp_path)
    process = run(loaded, tmp_path / "udp.mcap")
    local = run(loaded, tmp_path / "virtual.mcap", interface="virtual")
    assert process.status == local.status == "completed" and process.frames_lost == 0
    wanted = ["/can/frames", "/truth/state", "/truth/inputs", "/can/COMMAND_force", "/can/EST_kf_0"]
    a, b = topics(tmp_path / "udp.mcap", wanted), topics(tmp_path / "virtual.mcap", wanted)
    assert a == b
    # The plant got what the controller node commanded, tick for tick.
    commanded = [m["commanded"]["force"] for m in a["/truth/inputs"]]
    assert commanded == [m["force"] for m in a["/can/COMMAND_force"]]
    assert len(commanded) == 1200 and commanded[0] == pytest.approx(8.0 * 0.5 + 2.0 * 0.01 * 0.5, abs=1e-3)
    x2 = np.array([m["x2"] for m in a["/truth/state"]])
    assert abs(x2[-200:].mean() - 0.5) < 0.03  # integral action removes the static error (spring load)
    assert abs(x2[:5].mean()) < 0.01
    # The Kalman filter used the controller's commands: its estimate tracks the truth.
    xhat = np.array([m["xhat_x2"] for m in a["/can/EST_kf_0"]])
    assert np.max(np.abs(xhat[100:600] - x2[100:600])) < 1e-3


@pytest.mark.parametrize(
    "extra, message",
    [('[[inputs]]\nactuator = "force"\nsignal = 1.0\n', "inputs: the controller commands every actuator")],
)
def test_inputs_and_a_controller_exclude_each_other(tmp_path, extra, message):
    with pytest.raises(ScenarioError, match=message):
        load(tmp_path, PID_SCENARIO.replace("[[estimators]]", extra + "[[estimators]]"))


@pytest.mark.parametrize(
    "old, new, message",
    [
        ('kind = "pid"', 'kind = "pdi"', r"controller.kind: unknown controller 'pdi' \(did you mean 'pid'\?\)"),
        ('diagnosis = "kf"', 'diagnosis = "kff"', "controller.diagnosis: 'kff' is not an estimator"),
        ("kp = [8.0]", 'kp = "high"', "controller.params.kp: expected a list of numbers"),
        ('name = "kf"', 'name = "controller"', "the name 'controller' is the controller node's"),
    ],
)
def test_bad_controller_tables_name_the_field(tmp_path, old, new, message):
    with pytest.raises(ScenarioError, match=message):
        load(tmp_path, PID_SCENARIO.replace(old, new))


@pytest.mark.parametrize(
    "change, message",
    [
        ({"diagnosis": '"kf"'}, r"'kf' \(kalman\) does not publish fault_mask, which thrust-allocation reads"),
        ({"diagnosis": '""'}, "thrust-allocation reads fault_mask from a diagnosis node; name one of the estimators"),
    ],
)
def test_a_controller_must_listen_to_a_node_that_publishes_what_it_reads(tmp_path, change, message):
    text = scenario.load("vessel-fault-T1").text.replace('diagnosis = "fdi"', f"diagnosis = {change['diagnosis']}")
    text = (
        text.replace('name = "fdi"\nkind = "cofd"', 'name = "kf"\nkind = "kalman"')
        if change["diagnosis"] == '"kf"'
        else text
    )
    with pytest.raises(ScenarioError, match=message):
        load(tmp_path, text, "vessel.toml")


def test_clients_of_a_closed_loop_run_read_the_controllers_commands():
    from cosim.bus.client import Client

    codec = small_codec()
    bus = can.Bus(interface="virtual", channel="closed-loop-client")
    try:
        assert Client(None, codec, bus).assembler.upstream == {CONTROLLER: 0}  # a listener, e.g. cosim monitor
        assert Client("diag", codec, bus).assembler.upstream == {CONTROLLER: 0}
        assert Client(CONTROLLER, codec, bus, upstream={"diag": 1}).assembler.upstream == {"diag": 1}
        open_loop = Codec([Channel("y", "m", "", -1, 1, 1e-3)], [Channel("u", "N", "", -1, 1, 1e-3)], {}, fd=True)
        assert Client(None, open_loop, bus).assembler.upstream == {}
    finally:
        bus.shutdown()
