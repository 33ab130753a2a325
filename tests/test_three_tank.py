"""The three-tank MJCF model against the paper's model (IJC 2018, Sec. 4, eq. (57)-(59))."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import mjcf
from cosim.errors import ModelError
from cosim.plant.physics import Plant
from mjcf import three_tank as tt

INFO = mjcf.get("three_tank")
ORIFICES = ("flow13", "flow32", "flow20")


@pytest.fixture
def plant():
    return Plant(INFO, tt.SAMPLE_TIME, tt.PAPER_SENSORS)


def dof(model: mujoco.MjModel, joint: str) -> int:
    return int(model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint)])


def ode(h0, q1: float, q2: float, v: float, t_end: float) -> np.ndarray:
    """Eq. (57) with the erratum, solved to rtol 1e-10, sampled every second after t = 0."""
    sol = solve_ivp(
        lambda t, h: tt.level_rates(h, q1, q2, v),
        (0.0, t_end),
        h0,
        method="LSODA",
        rtol=1e-10,
        atol=1e-12,
        t_eval=np.arange(1.0, t_end + 0.5),
    )
    assert sol.success
    return sol.y.T


def test_trajectory_from_empty_tanks_matches_the_ode(plant):
    """600 s of constant inflows from empty tanks: every 1 s sample within 1e-4 m of (57).
    (Measured: 2.5e-4 cm = 2.5e-6 m, at t ≈ 280 s.)"""
    plant.reset({"h1": 0.0, "h2": 0.0, "h3": 0.0})
    levels = []
    for _ in range(600):
        plant.step(np.array([35.0, 35.0]), np.array([0.0]))
        levels.append(plant.state())
    error_cm = np.abs(np.array(levels) - ode([0.0, 0.0, 0.0], 35.0, 35.0, 0.0, 600.0))
    assert error_cm.max() < 1e-2  # cm, i.e. 1e-4 m
    np.testing.assert_allclose(levels[-1], [37.73, 20.88, 28.44], atol=0.01)  # the steady state


def test_trajectory_with_input_steps_matches_the_ode(plant):
    """From the operating point, zero-order-held steps of Q1, Q2 and v (each held 100 s)."""
    steps = [(35.0, 35.0, 0.0), (60.0, 10.0, 0.0), (0.0, 50.0, 0.02), (20.0, 0.0, -0.02)]
    h = np.array(tt.OPERATING_LEVELS)
    plant.reset()
    for q1, q2, v in steps:
        reference = ode(h, q1, q2, v, 100.0)
        levels = []
        for _ in range(100):
            plant.step(np.array([q1, q2]), np.array([v]))
            levels.append(plant.state())
        assert np.abs(np.array(levels) - reference).max() < 1e-2
        h = reference[-1]


def test_linearization_reproduces_the_papers_matrices(plant):
    """A and B of (59) to every printed digit (within half a unit of the last one), C exactly."""
    model = plant.linearize()
    half_unit_A = np.array([[5e-5, 5e-5, 5e-7], [5e-5, 5e-5, 5e-7], [5e-7, 5e-7, 5e-5]])
    half_unit_B = np.array([[5e-7, 5e-12], [5e-12, 5e-7], [5e-9, 5e-9]])
    assert np.all(np.abs(model.A - tt.PAPER_A) <= half_unit_A)
    assert np.all(np.abs(model.B - tt.PAPER_B) <= half_unit_B)
    np.testing.assert_allclose(model.C, tt.PAPER_C, atol=1e-9)
    assert np.array_equal(model.D, np.zeros((4, 2)))
    # E ∝ [1 1 1]: exactly in continuous time; the hold over T = 1 s lets tank 2 drain 0.55 % of it.
    np.testing.assert_allclose(model.E[:, 0], [1.0, 1.0, 1.0], rtol=6e-3)
    assert model.states == ("h1", "h2", "h3") and model.inputs == ("Q1", "Q2") and model.disturbances == ("v",)
    assert model.dt == tt.SAMPLE_TIME
    np.testing.assert_allclose(model.x_op, tt.OPERATING_LEVELS)
    np.testing.assert_allclose(model.u_op, tt.OPERATING_FLOWS)
    np.testing.assert_allclose(model.y_op, tt.PAPER_C @ tt.OPERATING_LEVELS)


def test_continuous_linearization_is_the_jacobian_of_eq_57(plant):
    model = plant.linearize(continuous=True)
    Ac, Bc, Ec = tt.continuous_model()
    np.testing.assert_allclose(model.A, Ac, rtol=0, atol=1e-9 * np.abs(Ac).max())
    np.testing.assert_allclose(model.B, Bc, rtol=1e-9)
    np.testing.assert_allclose(model.E, Ec, rtol=1e-9)
    # The continuous model the paper discretized, rounded to four decimals (module docstring).
    printed = np.array([[-0.0085, 0.0, 0.0085], [0.0, -0.0195, 0.0084], [0.0085, 0.0084, -0.0169]])
    np.testing.assert_allclose(model.A, printed, atol=5e-7)
    np.testing.assert_allclose(model.B, [[0.0065, 0.0], [0.0, 0.0065], [0.0, 0.0]], rtol=1e-9, atol=1e-15)


def test_linearization_elsewhere_and_by_stepping(plant):
    """At another point it is (57)'s Jacobian there; "step" (the simulation's own map, a first-order
    integrator at 10 ms) agrees with the exact discretization to ~2e-5."""
    h, u = np.array([30.0, 10.0, 20.0]), np.array([20.0, 25.0, 0.01])
    model = plant.linearize(x=h, u=u, continuous=True)
    Ac, _, _ = tt.continuous_model(tuple(h))
    np.testing.assert_allclose(model.A, Ac, atol=1e-9 * np.abs(Ac).max())
    exact, stepped = plant.linearize(), plant.linearize(method="step")
    assert np.abs(stepped.A - exact.A).max() < 5e-5
    assert np.abs(stepped.B - exact.B).max() < 1e-6 and np.abs(stepped.E - exact.E).max() < 6e-5
    with pytest.raises(ModelError, match="zero head"):
        plant.linearize(x=np.array([30.0, 10.0, 30.0]), continuous=True)  # h1 = h3: infinite slope


def test_quasi_static_reduction_is_the_slow_dynamics(plant):
    """The full linearization [levels, flows] has the inertance of the flows; its three slow
    eigenvalues (solved exactly as a 3x3 nonlinear eigenproblem, the 12x12 one spans 1e15) differ
    from the reduced model's by < 1e-5 relative."""
    m, T, T_pinv = plant.model, plant.tendons, plant.tendons_pinv
    d = mujoco.MjData(m)
    q0, v0, c0 = plant.data.qpos.copy(), plant.data.qvel.copy(), plant.data.ctrl.copy()

    def force(dh: np.ndarray, dv: np.ndarray) -> np.ndarray:
        d.qpos[:], d.qvel[:], d.ctrl[:] = q0 + T_pinv @ dh, v0 + dv, c0
        mujoco.mj_forward(m, d)
        return d.qfrc_smooth.copy()

    f_h = np.array([(force(e * 1e-3, 0 * v0) - force(-e * 1e-3, 0 * v0)) / 2e-3 for e in np.eye(3)]).T
    steps = 1e-6 * np.abs(v0) + 1e-18
    f_v = np.array([(force(0 * e[:3], e * s) - force(0 * e[:3], -e * s)) / (2 * s) for e, s in zip(np.eye(6), steps)]).T
    M = np.diag([m.body_mass[m.jnt_bodyid[j]] for j in range(m.njnt)])
    reduced = np.sort(np.linalg.eigvals(plant.linearize(continuous=True).A).real)
    full = reduced.copy()
    for i in range(3):  # λ h = T (λ M − f_v)⁻¹ f_h h
        for _ in range(20):
            eig = np.linalg.eigvals(T @ np.linalg.solve(full[i] * M - f_v, f_h)).real
            full[i] = eig[np.argmin(np.abs(eig - full[i]))]
    assert np.all(np.abs(full - reduced) < 1e-5 * np.abs(reduced))
    assert np.all(np.abs(full - reduced) > 0)  # the inertance is there


def test_mujoco_forces_are_torricelli(plant):
    """At random levels with the flows at Torricelli's values, pressure and orifice loss balance
    on every orifice joint, and the level rates are eq. (57)'s right-hand side."""
    m, d = plant.model, plant.data
    rng = np.random.default_rng(0)
    for _ in range(20):
        h = rng.uniform(1.0, 60.0, size=3)
        q1, q2, v = rng.uniform(0.0, 100.0), rng.uniform(0.0, 100.0), rng.uniform(-0.1, 0.1)
        plant.set_state(h)
        q13, q32, q20 = tt._flows(h / 100.0)
        for name, q in zip(ORIFICES, (q13, q32, q20)):
            d.qvel[dof(m, name)] = q
        d.qvel[dof(m, "pump1")], d.qvel[dof(m, "pump2")], d.qvel[dof(m, "inflow_v")] = q1 * 1e-6, q2 * 1e-6, v / 6500.0
        mujoco.mj_forward(m, d)
        for name, head in zip(ORIFICES, (h[0] - h[2], h[2] - h[1], h[1])):
            pressure = tt.RHO * tt.G * abs(head) / 100.0
            assert abs(d.qfrc_passive[dof(m, name)]) < 1e-9 * pressure  # spring + damper
        np.testing.assert_allclose(plant.tendons @ d.qvel, tt.level_rates(h, q1, q2, v), rtol=1e-9, atol=1e-12)


def test_set_state_puts_the_flows_at_torricelli(plant):
    h = np.array([50.0, 10.0, 35.0])
    plant.data.ctrl[:] = [40.0, 20.0, 0.05]
    plant.set_state(h)
    np.testing.assert_allclose(plant.state(), h, rtol=1e-14)
    flows = [plant.data.qvel[dof(plant.model, name)] for name in ORIFICES]
    np.testing.assert_allclose(flows, tt._flows(h / 100.0), rtol=1e-9)
    np.testing.assert_allclose(plant.tendons @ plant.data.qvel, tt.level_rates(h, 40.0, 20.0, 0.05), rtol=1e-7)


def _levels(plant: Plant, start: dict[str, float], pumps: list[float], leak: float, ticks: int) -> np.ndarray:
    """The levels tick after tick from ``start``, with constant pump flows and unknown input v."""
    plant.reset(start)
    levels = []
    for _ in range(ticks):
        plant.step(np.array(pumps), np.array([leak]))
        levels.append(plant.state())
    return np.array(levels)


def test_levels_stay_between_empty_and_full():
    plant = Plant(INFO, 0.1)
    # Tank 2 drains (through the drain and into tank 3) and, with no inflow, stays empty.
    levels = _levels(plant, {"h1": 0.0, "h2": 5.0, "h3": 0.0}, [0.0, 0.0], 0.0, 2000)
    assert levels.min() > -1e-4 and np.abs(levels[-1]).max() < 1e-3
    # Pumping at full flow into a full tank 1: its level holds at h_max (the surplus goes on
    # through the pipes, as in a closed tank; see three_tank.xml), and so do the others in turn.
    levels = _levels(plant, {"h1": 61.0, "h2": 40.0, "h3": 55.0}, [100.0, 100.0], 0.0, 3000)
    assert levels.max() < tt.H_MAX + 0.01
    np.testing.assert_allclose(levels[-1], tt.H_MAX, atol=0.01)
    # A leak from empty tanks cannot take them below empty.
    assert _levels(plant, {"h1": 2.0, "h2": 1.0, "h3": 1.5}, [0.0, 0.0], -0.1, 100).min() > -0.05


def test_the_operating_inflows_hold_the_operating_levels(plant):
    """The keyframe's inflows cancel dh1/dt and dh2/dt of (57) at the paper's levels; tank 3 has no
    pump and rises 0.003 cm/s. The paper's own 35 cm^3/s would move tank 2 by 0.147 cm/s."""
    h = np.array(tt.OPERATING_LEVELS)
    np.testing.assert_allclose(tt.level_rates(h, *tt.OPERATING_FLOWS), [0.0, 0.0, 0.0030], atol=5e-6)
    assert tt.level_rates(h, *tt.PAPER_FLOWS)[1] == pytest.approx(0.1465, abs=1e-4)
    plant.reset()
    np.testing.assert_allclose(plant.data.ctrl[:2], tt.OPERATING_FLOWS)
    for _ in range(10):
        plant.step(np.array(tt.OPERATING_FLOWS), np.array([0.0]))
    moved = plant.state() - h
    np.testing.assert_allclose(moved, ode(h, *tt.OPERATING_FLOWS, 0.0, 10.0)[-1] - h, atol=1e-5)
    assert np.abs(moved).max() < 0.03  # the paper's inflows: 1.5 cm in tank 2
    plant.reset()


def test_disturbance_raises_all_levels_equally():
    """Over one 10 ms step from the operating point, v adds v dt to every level (E = [1 1 1])."""
    plant = Plant(INFO, 0.01)
    plant.step(np.array(tt.OPERATING_FLOWS), np.array([0.0]))
    without = plant.state()
    plant.reset()
    plant.step(np.array(tt.OPERATING_FLOWS), np.array([0.5]))
    np.testing.assert_allclose(plant.state() - without, 0.5 * 0.01 * np.ones(3), rtol=1e-4)


def test_state_is_the_levels(plant):
    assert plant.nx == 3 and plant.state_names == ("h1", "h2", "h3")
    np.testing.assert_allclose(plant.state(), tt.OPERATING_LEVELS)
    np.testing.assert_allclose(plant.sensors(), tt.PAPER_C @ tt.OPERATING_LEVELS)
    plant.reset({"h2": 20.0})
    np.testing.assert_allclose(plant.state(), [45.0, 20.0, 30.0])
    np.testing.assert_allclose(plant.sensors(), tt.PAPER_C @ [45.0, 20.0, 30.0])
    plant.set_state(np.array([10.0, 11.0, 12.0]))
    np.testing.assert_allclose(plant.state(), [10.0, 11.0, 12.0], rtol=1e-14)
    # The keyframe is the operating point with its quasi-steady flows.
    key = Plant(INFO, 1.0)
    fresh = mujoco.MjData(key.model)
    mujoco.mj_resetDataKeyframe(key.model, fresh, 0)
    np.testing.assert_allclose(fresh.qvel, key.data.qvel, rtol=1e-9, atol=1e-20)


def test_model_parameters(plant):
    m = plant.model
    S, rho = tt.PIPE, tt.RHO
    for name, a in zip(ORIFICES, (tt.A1, tt.A3, tt.A2)):
        j = dof(m, name)
        assert m.dof_damping[j] == 0
        np.testing.assert_allclose(m.dof_dampingpoly[j], [rho / (2 * (a * S) ** 2), 0.0], rtol=1e-15)
    level = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TENDON, "h1")
    np.testing.assert_allclose(m.tendon_stiffness[level], rho * tt.G * tt.AREA / 1e4, rtol=1e-15)
    np.testing.assert_allclose(m.tendon_range[level], [0.0, tt.H_MAX])
    np.testing.assert_allclose(
        plant.tendons,
        100.0 / tt.AREA * np.array([[-1, 0, 0, 1, 0, 1], [0, 1, -1, 0, 1, 1], [1, -1, 0, 0, 0, 1]]),
        rtol=1e-15,
    )
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_DISCRETE
    assert tt.SAMPLE_TIME / m.opt.timestep == 100


def test_state_tendons_are_checked():
    with pytest.raises(ModelError, match="no tendon named"):
        Plant(dataclasses.replace(INFO, state_tendons=("h1", "h2", "nope")), 1.0)
    with pytest.raises(ModelError, match="not independent"):
        Plant(dataclasses.replace(INFO, state_tendons=("h1", "h1_x10", "h2")), 1.0)
    with pytest.raises(ModelError, match="3 states but 2 state tendons"):
        Plant(dataclasses.replace(INFO, state_tendons=("h1", "h2")), 1.0)
