"""Unknown inputs: driven by [[disturbances]], applied to the plant, logged as truth, never on the bus."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from cosim import scenario
from cosim.errors import ScenarioError
from cosim.log.reader import LogReader
from cosim.plant.statespace import StateSpacePlant
from cosim.run import run

PLANT = """
name = "dist"
duration = 1.0
sample_time = 0.1

[plant]
model = "state-space"
initial_state = { x1 = 1.0 }

[plant.state_space]
A = [[-1.0, 0.5], [0.0, -2.0]]
B = [[0.0], [1.0]]
C = [[1.0, 0.0], [0.0, 1.0]]
E = [[1.0], [0.5]]
disturbances = ["leak"]
"""


def test_state_space_plant_integrates_the_unknown_input_exactly():
    s = scenario.parse(PLANT)
    spec = s.plant.state_space
    plant = StateSpacePlant(spec, s.plant_info, 0.1)
    plant.reset({"x1": 1.0})
    plant.step(np.array([2.0]), np.array([-3.0]))
    A, BE = np.array(spec.A), np.array([[0.0, 1.0], [1.0, 0.5]])
    big = expm(np.block([[A, BE], [np.zeros((2, 4))]]) * 0.1)
    expected = big[:2, :2] @ np.array([1.0, 0.0]) + big[:2, 2:] @ np.array([2.0, -3.0])
    np.testing.assert_allclose(plant.state(), expected, rtol=1e-12)
    model = plant.linearize()
    assert model.disturbances == ("leak",) and model.E.shape == (2, 1)
    np.testing.assert_allclose(model.E[:, 0], big[:2, 3], rtol=1e-12)
    assert plant.linearize(continuous=True).E.tolist() == [[1.0], [0.5]]


def test_an_unknown_disturbance_name_is_a_clear_error(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(PLANT + '\n[[disturbances]]\ninput = "lek"\nsignal = 1.0\n')
    with pytest.raises(
        ScenarioError, match=r"disturbances\[0\]\.input: .*no disturbance input 'lek' \(did you mean 'leak'\?\)"
    ):
        scenario.load(path)


def test_disturbance_is_logged_as_truth_and_not_sent(tmp_path):
    path = tmp_path / "dist.toml"
    path.write_text(
        PLANT + '\n[[disturbances]]\ninput = "leak"\nsignal = { kind = "sine", amplitude = 2.0, frequency = 1.0 }\n'
    )
    result = run(scenario.load(path), tmp_path / "dist.mcap")
    with LogReader(result.path) as reader:
        inputs = [msg for _, _, msg in reader.messages(["/truth/inputs"])]
        dbc = reader.attachments()["cosim.dbc"].decode()
    assert [round(m["disturbance"]["leak"], 12) for m in inputs] == [
        round(2.0 * np.sin(2 * np.pi * m["t"]), 12) for m in inputs
    ]
    assert "leak" not in dbc
