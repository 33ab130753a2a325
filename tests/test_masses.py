"""The coupled-masses MJCF model against the paper's continuous model (TAC 2024, Sec. VII)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import mjcf
from cosim.errors import ModelError
from cosim.plant.physics import Plant
from estimators.design import zoh_discretize
from mjcf import masses

THREE = ["x1", "x2", "x1_minus_x2"]
FOUR = ["x1", "x2", "x1_minus_x2", "x2_minus_x1"]


@pytest.fixture
def plant():
    return Plant(mjcf.get("masses"), 0.01, THREE)


def test_model_parameters_match_table_i(plant):
    m = plant.model
    p = {k: v.value for k, v in masses.PARAMETERS.items()}
    body = lambda name: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)  # noqa: E731
    joint = lambda name: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)  # noqa: E731
    tendon = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TENDON, "coupling")
    assert m.body_mass[body("mass1")] == p["m1"]
    assert m.body_mass[body("mass2")] == p["m2"]
    assert m.jnt_stiffness[joint("x1")] == p["k1"]
    assert m.dof_damping[m.jnt_dofadr[joint("x1")]] == p["d1"]
    assert m.jnt_stiffness[joint("x2")] == 0 and m.dof_damping[m.jnt_dofadr[joint("x2")]] == 0
    assert m.tendon_stiffness[tendon] == p["k2"]
    assert m.tendon_damping[tendon] == p["d2"]


def test_mujoco_dynamics_are_the_papers_continuous_model(plant):
    """mj_forward's acceleration equals A0 x + B0 u at random states and inputs."""
    A0, B0 = masses.continuous_model()
    rng = np.random.default_rng(0)
    for _ in range(20):
        x, u = rng.normal(size=4), rng.normal(size=1)
        plant.set_state(x)
        plant.data.ctrl[:] = u
        mujoco.mj_forward(plant.model, plant.data)
        xdot = np.concatenate([plant.data.qvel, plant.data.qacc])
        np.testing.assert_allclose(xdot, A0 @ x + B0 @ u, rtol=0, atol=1e-12)


@pytest.mark.parametrize("method", ["zoh", "step"])
def test_linearization_matches_exact_discretization(method):
    """Discrete (A, B) from MuJoCo match expm(A0 τ) and its input integral to better than 1e-8."""
    plant = Plant(mjcf.get("masses"), 0.01, FOUR)
    model = plant.linearize(method=method)
    A0, B0 = masses.continuous_model()
    A, B = zoh_discretize(A0, B0, 0.01)
    assert np.max(np.abs(model.A - A)) < 1e-8
    assert np.max(np.abs(model.B - B)) < 1e-8
    assert np.array_equal(model.C, masses.output_matrix(FOUR))  # exactly
    assert np.array_equal(model.D, np.zeros((4, 1)))
    assert model.states == ("x1", "x2", "v1", "v2") and model.outputs == tuple(FOUR) and model.dt == 0.01


def test_linearization_away_from_the_origin(plant):
    """A linear plant has the same Jacobians at any operating point."""
    model = plant.linearize(x=np.array([0.3, -0.7, 0.2, 0.1]), u=np.array([2.5]))
    A, B = zoh_discretize(*masses.continuous_model(), 0.01)
    assert np.max(np.abs(model.A - A)) < 1e-8 and np.max(np.abs(model.B - B)) < 1e-8
    np.testing.assert_allclose(model.C, masses.output_matrix(THREE), atol=1e-9)
    np.testing.assert_allclose(model.x_op, [0.3, -0.7, 0.2, 0.1])


def test_continuous_linearization(plant):
    model = plant.linearize(continuous=True)
    A0, B0 = masses.continuous_model()
    assert model.dt is None
    np.testing.assert_allclose(model.A, A0, atol=1e-9)
    np.testing.assert_allclose(model.B, B0, atol=1e-9)


def test_simulation_follows_the_exact_discrete_model(plant):
    """1000 ticks of mj_step (RK4, 10 substeps per tick, ZOH input) against x⁺ = A x + B u."""
    A, B = zoh_discretize(*masses.continuous_model(), 0.01)
    x = np.array([0.2, -0.1, 0.0, 0.3])
    plant.set_state(x)
    worst = 0.0
    for k in range(1000):
        u = np.array([np.sin(2 * np.pi * 0.5 * k * 0.01)])
        plant.step(u)
        x = A @ x + B @ u
        worst = max(worst, np.max(np.abs(plant.state() - x)))
        np.testing.assert_allclose(plant.sensors(), masses.output_matrix(THREE) @ x, atol=1e-9)
    assert worst < 1e-9


def test_reset_to_keyframe_and_initial_state(plant):
    plant.step(np.array([5.0]))
    plant.reset({"x1": 0.5, "v2": -0.25})
    np.testing.assert_array_equal(plant.state(), [0.5, 0.0, 0.0, -0.25])
    np.testing.assert_array_equal(plant.sensors(), [0.5, 0.0, 0.5])


def test_sample_time_must_be_a_whole_number_of_timesteps():
    with pytest.raises(ModelError, match=r"sample_time = 0.0105 s is not a whole multiple of the timestep 0.001 s"):
        Plant(mjcf.get("masses"), 0.0105)


def test_unknown_plant_lists_known_ones():
    with pytest.raises(KeyError, match="known plants: masses"):
        mjcf.get("tanks")
