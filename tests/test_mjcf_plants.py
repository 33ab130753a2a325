"""Plants from the user's own MJCF file (``[plant] model = "robot.xml"``), described from the model
itself: a pendulum, a cart with a hanging pole and a rigid body of six degrees of freedom, none
like a built-in, each run with a bias fault and a Kalman filter designed on its linearization; and
an estimator from a Python file next to the scenario. Bad models give one line."""

from __future__ import annotations

import csv
import math
import textwrap
from pathlib import Path

import numpy as np
import pytest

from cosim import api
from cosim.analysis.export import export
from cosim.errors import ScenarioError
from cosim.plant import build_plant

NOISE = 1e-3
MODELS = Path(__file__).parent / "data" / "mjcf"  # none like a built-in plant

PENDULUM = (MODELS / "pendulum.xml").read_text()
CART_POLE = (MODELS / "cart_pole.xml").read_text()
RIGID_BODY = (MODELS / "rigid_body.xml").read_text()


def scenario_text(model: str, inputs: list[tuple[str, float, float]], bias: float, sensor: str) -> str:
    signals = "".join(
        f'[[inputs]]\nactuator = "{a}"\nsignal = {{ kind = "sine", amplitude = {amp}, frequency = {f} }}\n'
        for a, amp, f in inputs
    )
    return textwrap.dedent(
        f"""
        name = "my-plant"
        duration = 6.0
        sample_time = 0.01
        [plant]
        model = "{model}"
        {signals}
        [[noise]]
        kind = "gaussian_noise"
        std = {NOISE}
        [[faults]]
        kind = "bias"
        sensors = ["{sensor}"]
        value = {bias}
        start = 4.0
        [[estimators]]
        name = "kalman"
        kind = "kalman"
        params = {{ measurement_std = {NOISE}, process_std = 1e-3 }}
        """
    )


CASES = {
    "pendulum": (PENDULUM, [("torque", 0.05, 0.2)], "angle"),
    "cart-pole": (CART_POLE, [("push", 0.5, 0.2)], "angle"),
    "rigid-body": (RIGID_BODY, [("fx", 0.2, 0.3), ("my", 0.001, 0.2), ("mz", 0.001, 0.25)], "gnss_0"),
}


def position_errors(log, start: float, end: float) -> dict[str, float]:
    """RMS of x − x̂ per position state (a joint's angle or displacement) over start ≤ t < end."""
    table = export(log, "csv", log.with_suffix(".csv")).path
    with open(table) as stream:
        rows = [row for row in csv.DictReader(stream) if start <= float(row["t [s]"]) < end]
    columns = [c for c in rows[0] if c.startswith("state.") and "_dot" not in c]
    errors = {}
    for column in columns:
        state = column.split()[0].removeprefix("state.")
        (estimate,) = [c for c in rows[0] if c.startswith(f"kalman.xhat_{state} ")]
        errors[state] = math.sqrt(sum((float(r[column]) - float(r[estimate])) ** 2 for r in rows) / len(rows))
    return errors


@pytest.mark.parametrize("case", CASES)
def test_an_mjcf_plant_of_the_users_is_estimated_at_the_noise_level_until_its_fault(case, tmp_path):
    xml, inputs, sensor = CASES[case]
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "plant.xml").write_text(xml)
    path = tmp_path / "scenario.toml"
    path.write_text(scenario_text("models/plant.xml", inputs, 0.02, sensor))  # relative to the scenario
    result = api.run(api.load_scenario(path), tmp_path / "run.mcap", in_process=True)
    assert result.status == "completed"
    before = position_errors(result.path, 0.0, 4.0)
    assert before and all(error < 1.5 * NOISE for error in before.values()), before  # measured: at the noise
    after = position_errors(result.path, 4.5, 6.0)
    assert max(after.values()) > 5 * NOISE  # and the 0.02 bias from 4 s is seen


def scenario_of(tmp_path, xml: str, plant: str = "") -> object:
    """A scenario of the model alone (its table ``[plant.mjcf]`` from ``plant``)."""
    (tmp_path / "plant.xml").write_text(xml)
    (tmp_path / "only.toml").write_text(
        f'name = "only"\nduration = 1.0\nsample_time = 0.01\n[plant]\nmodel = "plant.xml"\n{plant}\n'
        '[[estimators]]\nname = "kalman"\nkind = "kalman"\n'
    )
    return api.load_scenario(tmp_path / "only.toml").scenario


def test_the_model_names_the_signals_and_the_operating_point(tmp_path):
    info = scenario_of(tmp_path, RIGID_BODY).plant_info
    assert [c.name for c in info.sensors] == ["gnss_0", "gnss_1", "gnss_2", "roll", "pitch", "yaw"]
    assert [c.unit for c in info.sensors] == ["m", "m", "m", "rad", "rad", "rad"]
    assert [c.name for c in info.states][:6] == ["x", "y", "z", "roll", "pitch", "yaw"]
    assert [c.unit for c in info.states][6:9] == ["m/s", "m/s", "m/s"] and info.keyframe == ""
    assert [c.name for c in info.actuators] == ["fx", "fy", "fz", "mx", "my", "mz"]
    cart = scenario_of(tmp_path, CART_POLE, '[plant.mjcf]\ndisturbances = ["push"]')
    assert cart.plant_info.keyframe == "centre" and cart.actuators == () and cart.disturbance_inputs == ("push",)
    model = build_plant(cart).linearize()
    assert model.states == ("cart", "pole", "cart_dot", "pole_dot") and model.E.shape == (4, 1)
    moduli = np.sort(np.abs(np.linalg.eigvals(model.A)))  # the cart's position integrates; the pole swings, damped
    assert moduli[-1] == pytest.approx(1.0, abs=1e-9) and moduli[-2] < 1.0


BAD = {
    "no sensors": (
        '<mujoco><worldbody><body><joint type="slide"/><geom size="0.1"/></body></worldbody></mujoco>',
        "has no <sensor>",
    ),
    "a free joint": (
        '<mujoco><worldbody><body><freejoint/><geom size="0.1"/><site name="s"/></body></worldbody>'
        '<sensor><framepos objtype="site" objname="s"/></sensor></mujoco>',
        "is a ball or free joint",
    ),
    "broken XML": ('<mujoco><worldbody><body><geom size="0.1"></body></worldbody></mujoco>', "could not compile"),
    "an unknown element": ("<mujoco><worldbody><bogus/></worldbody></mujoco>", "could not compile"),
}


@pytest.mark.parametrize("case", BAD)
def test_a_model_that_cannot_be_a_plant_is_one_line(case, tmp_path):
    xml, message = BAD[case]
    with pytest.raises(ScenarioError) as refused:
        scenario_of(tmp_path, xml)
    assert message in str(refused.value) and "\n" not in str(refused.value)


def test_a_missing_model_file_and_an_unknown_disturbance_are_one_line(tmp_path):
    with pytest.raises(ScenarioError, match=r"no MJCF file at .*nowhere\.xml \(a path relative to the scenario"):
        api.load_scenario(None, {"plant.model": str(tmp_path / "nowhere.xml")})
    with pytest.raises(ScenarioError, match=r"plant.mjcf.disturbances: plant.xml has no actuator 'wind'"):
        scenario_of(tmp_path, PENDULUM, '[plant.mjcf]\ndisturbances = ["wind"]')


OBSERVER = '''
"""An observer of the user's, in a file next to the scenario."""

from dataclasses import dataclass

import numpy as np
from scipy.signal import place_poles

from estimators import Estimate, Estimator


@dataclass(frozen=True)
class Params:
    poles: tuple[float, ...] = (0.8, 0.85)


class Luenberger(Estimator):
    """x̂⁺ = A x̂ + B u + L (y − C x̂ − D u), L placing spec(A − L C) at ``poles``."""

    kind = "luenberger"
    Params = Params

    def __init__(self, model, params, sample_time=None):
        super().__init__(model, params, sample_time)
        self.L = place_poles(model.A.T, model.C.T, params.poles).gain_matrix.T
        self.x = np.zeros(model.n)

    def _step(self, dy, du):
        m = self.model
        estimate = self.x.copy()
        self.x = m.A @ self.x + m.B @ du + self.L @ (dy - m.C @ self.x - m.D @ du)
        return Estimate(estimate)
'''


def test_an_estimator_from_a_python_file_next_to_the_scenario_runs_in_process_and_as_a_node(tmp_path):
    (tmp_path / "pendulum.xml").write_text(PENDULUM)
    (tmp_path / "observers.py").write_text(OBSERVER)
    text = scenario_text("pendulum.xml", [("torque", 0.05, 0.2)], 0.02, "angle")
    text += '[[estimators]]\nname = "mine"\nkind = "observers.py:Luenberger"\nparams = { poles = [0.6, 0.7] }\n'
    (tmp_path / "scenario.toml").write_text(text)
    loaded = api.load_scenario(tmp_path / "scenario.toml")
    assert loaded.scenario.estimators[1].kind == f"{tmp_path / 'observers.py'}:Luenberger"  # made absolute
    for name, in_process in (("in-process", True), ("nodes", False)):
        result = api.run(loaded, tmp_path / f"{name}.mcap", in_process=in_process)
        assert result.status == "completed", result.error
        mine = api.metrics(result.path)["estimators"]["mine"]
        assert mine["rms_pre_fault"] < 0.05 and mine["ticks_scored"] == 600
