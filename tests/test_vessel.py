"""The vessel plant (Cristofaro & Johansen, Sec. 4) against the paper's M, D, G and eq. (23)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import mjcf
from cosim.bus.codec import signal_bits
from cosim.plant.physics import Plant
from estimators.design import zoh_discretize
from mjcf import _body_damping, vessel
from mjcf.vessel import DISTURBANCE_BOUND, PAPER_D, PAPER_M, EnvironmentDisturbance, environment_disturbance

A_X, A_Y = PAPER_M[0, 0] - vessel.MASS, PAPER_M[1, 1] - vessel.MASS  # armature of the slides


@pytest.fixture(scope="module")
def plant() -> Plant:
    return Plant(mjcf.get("vessel"), 0.1)


def at(plant: Plant, psi: float, nu=(0.0, 0.0, 0.0), ctrl=None) -> mujoco.MjData:
    """Fresh data at position 0, heading psi, body velocity nu, after mj_forward."""
    d = mujoco.MjData(plant.model)
    d.qpos[:] = [0.0, 0.0, psi]
    d.qvel[:] = vessel.rotation(psi) @ np.asarray(nu, dtype=float)
    if ctrl is not None:
        d.ctrl[:] = ctrl
    plant.forward(d)
    return d


def full_inertia(plant: Plant, d: mujoco.MjData) -> np.ndarray:
    qM = np.zeros((plant.model.nv, plant.model.nv))
    mujoco.mj_fullM(plant.model, d, qM)
    return qM


def moment_matrix(plant: Plant, d: mujoco.MjData) -> np.ndarray:
    """The actuator moment matrix, shape (nu, nv): generalized force per unit ctrl."""
    m = plant.model
    dense = np.zeros((m.nu, m.nv))
    mujoco.mju_sparse2dense(dense, d.actuator_moment, d.moment_rownnz, d.moment_rowadr, d.moment_colind)
    return dense


def test_thruster_matrix_is_built_from_the_papers_geometry():
    G = vessel.thruster_matrix()
    d1, phi1, phi2 = 20.0, np.pi + 0.3, np.pi - 0.3
    assert G.shape == (3, 8)
    np.testing.assert_array_equal(G[:2], [[1, 0, 1, 0, 1, 0, 0, 0], [0, 1, 0, 1, 0, 1, 1, 1]])
    np.testing.assert_allclose(
        G[2, :4], [d1 * np.sin(phi1), d1 * np.cos(phi1), d1 * np.sin(phi2), d1 * np.cos(phi2)], rtol=1e-15
    )
    np.testing.assert_allclose(G[2, :4], [-5.9104041, -19.1067298, 5.9104041, -19.1067298], atol=1e-6)
    np.testing.assert_allclose(G[2, 4:], [0.0, 18.5, 30.0, 35.0], atol=1e-12)  # φ3 = φ4 = φ5 = 0
    # The thruster triples of the COFD observers (Sec. 4: R⁽ʰ⁾[W_i W_j W_k] = I) are independent.
    for columns in [(0, 1, 2), (2, 3, 0), (4, 5, 0), (6, 7, 0)]:
        assert np.linalg.matrix_rank(G[:, columns]) == 3


def test_paper_model_is_eq_23():
    A, B_tau, B_u, C = vessel.paper_model()
    Minv = np.linalg.inv(PAPER_M)
    np.testing.assert_array_equal(A[:3, 3:], np.eye(3))
    np.testing.assert_allclose(A[3:, 3:], -Minv @ PAPER_D)
    np.testing.assert_allclose(B_tau[3:], Minv)
    np.testing.assert_allclose(B_u, B_tau @ vessel.thruster_matrix())
    np.testing.assert_array_equal(C, np.eye(6))
    assert not np.any(A[:, :3]) and not np.any(B_tau[:3])
    A90 = vessel.paper_model(np.pi / 2)[0]
    np.testing.assert_allclose(A90[:3, 3:], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)


def test_joint_space_inertia_at_heading_zero_is_M(plant):
    np.testing.assert_allclose(full_inertia(plant, at(plant, 0.0)), PAPER_M, rtol=1e-13, atol=1e-6)


@pytest.mark.parametrize("degrees", [10.0, 45.0, 90.0, -135.0])
def test_inertia_away_from_heading_zero_differs_by_the_world_frame_added_mass_only(plant, degrees):
    """Body-frame inertia Tᵀ qM T = M + (a_y − a_x)[s², sc; sc, −s²] (vessel.xml, INERTIA): the
    sway–yaw coupling and the yaw inertia turn with the hull exactly."""
    psi = np.radians(degrees)
    T = vessel.rotation(psi)
    body = T.T @ full_inertia(plant, at(plant, psi)) @ T
    s, c = np.sin(psi), np.cos(psi)
    expected = PAPER_M + (A_Y - A_X) * np.array([[s * s, s * c, 0.0], [s * c, -s * s, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(body, expected, rtol=1e-12, atol=1e-5)


def test_the_documented_cost_at_ninety_degrees(plant):
    """The figures in vessel.xml: +66 % surge mass, −40 % sway mass, time constants 141 s and 28 s."""
    T = vessel.rotation(np.pi / 2)
    body = T.T @ full_inertia(plant, at(plant, np.pi / 2)) @ T
    assert body[0, 0] / PAPER_M[0, 0] - 1 == pytest.approx(0.66, abs=0.005)
    assert body[1, 1] / PAPER_M[1, 1] - 1 == pytest.approx(-0.40, abs=0.005)

    def time_constants(M):  # of ν' = −M⁻¹ D ν, slowest first
        return np.sort(1.0 / np.linalg.eigvals(np.linalg.solve(M, PAPER_D)).real)[::-1]

    np.testing.assert_allclose(time_constants(PAPER_M), [85.0, 47.5, 11.6], rtol=0.005)
    np.testing.assert_allclose(time_constants(body), [141.0, 28.1, 11.6], rtol=0.005)


@pytest.mark.parametrize("psi", [0.0, 0.4, np.pi / 2, -2.5])
def test_damping_force_is_minus_D_nu_in_the_body_frame(plant, psi):
    """qfrc_passive = [P(ψ) 0; 0 1](−D ν) at any heading, including D's skew (sway–yaw) part."""
    rng = np.random.default_rng(7)
    for nu in [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 0.1), tuple(rng.normal(size=3) * [2.0, 2.0, 0.05])]:
        d = at(plant, psi, nu)
        expected = vessel.rotation(psi) @ (-PAPER_D @ np.asarray(nu))
        np.testing.assert_allclose(d.qfrc_passive, expected, rtol=1e-12, atol=1e-6)


def test_body_damping_callback_leaves_other_models_alone(plant):
    masses = Plant(mjcf.get("masses"), 0.01)
    d = masses.data
    d.qvel[:] = [0.3, -0.2]
    with plant.physics():  # the vessel's callback is installed: it hands the masses on (to nothing)
        assert mujoco.get_mjcb_passive() is not None
        mujoco.mj_forward(masses.model, d)
    assert _body_damping.layout(masses.model) is None and _body_damping.forces(masses.model) is None
    np.testing.assert_allclose(
        d.qfrc_passive, [-5e-3 * 0.3 - 9e-3 * 0.5, 9e-3 * 0.5], rtol=1e-12
    )  # d1 x1', d2 (x1' - x2')


def test_nothing_of_the_vessel_outlives_a_call():
    """Loading, resetting, stepping and linearizing the vessel leave mjcb_passive as they found it;
    outside its calls the raw model has no ΔD (MuJoCo alone: the hull turns, as in the viewer)."""
    assert mujoco.get_mjcb_passive() is None
    vessel_plant = Plant(mjcf.get("vessel"), 0.1)
    vessel_plant.step(vessel_plant.data.ctrl[:8].copy())
    vessel_plant.linearize()
    vessel_plant.linearize(method="step")
    vessel_plant.reset({"psi": 0.3})
    assert mujoco.get_mjcb_passive() is None
    d = at(vessel_plant, 0.0, (0.0, 1.0, 0.0))
    bare = mujoco.MjData(vessel_plant.model)
    bare.qvel[:] = d.qvel
    mujoco.mj_forward(vessel_plant.model, bare)
    np.testing.assert_allclose(bare.qfrc_passive, [0.0, -PAPER_D[0, 0], 0.0])  # joint damping only
    np.testing.assert_allclose(d.qfrc_passive, -PAPER_D[:, 1], rtol=1e-12)


def test_a_foreign_callback_is_restored_and_still_serves_its_models(plant):
    """A callback someone else installed stays installed across the vessel's calls and keeps
    acting on other models inside them; the vessel's forces apply to the vessel only."""
    masses = Plant(mjcf.get("masses"), 0.01)
    seen: list[str] = []

    def foreign(model, data):
        seen.append("masses" if model is masses.model else "other")

    mujoco.set_mjcb_passive(foreign)
    try:
        with plant.physics():
            mujoco.mj_forward(masses.model, masses.data)
            mujoco.mj_forward(plant.model, plant.data)
            with plant.physics():  # nested: nothing changes
                mujoco.mj_forward(masses.model, masses.data)
        assert mujoco.get_mjcb_passive() is foreign
        assert seen == ["masses", "masses"]
        plant.step(plant.data.ctrl[:8].copy())
        assert mujoco.get_mjcb_passive() is foreign and seen == ["masses", "masses"]
    finally:
        mujoco.set_mjcb_passive(None)


def test_an_error_inside_a_call_restores_the_callback(plant):
    with pytest.raises(RuntimeError, match="inside"):
        with plant.physics():
            raise RuntimeError("inside")
    assert mujoco.get_mjcb_passive() is None
    with plant.physics():  # the lock was released too
        pass


def test_scoped_damping_is_bit_identical_to_the_global_callback(plant):
    """The per-call damping (``_body_damping.forces``, installed for each step) and the process-wide
    callback the plant used before (``_body_damping.passive``, installed once) give the same bits:
    300 ticks with turning thrust and a disturbance, the hull sweeping through 0.85 rad."""
    rng = np.random.default_rng(5)
    inputs = [(rng.normal(size=8) * 2e5, rng.normal(size=3) * 1e5) for _ in range(300)]
    inputs = [(u + [0, 0, 0, 0, 0, 4e5, 0, 0], b) for u, b in inputs]  # a yaw moment: the heading sweeps
    plant.reset({"psi": -0.4, "r": 0.01})
    start = (plant.data.qpos.copy(), plant.data.qvel.copy(), plant.data.ctrl.copy())
    scoped = []
    for u, b in inputs:
        plant.step(u, b)
        scoped.append(np.concatenate([plant.state(), plant.data.sensordata, plant.data.qacc]))
    m, d = plant.model, mujoco.MjData(plant.model)
    d.qpos[:], d.qvel[:], d.ctrl[:] = start
    mujoco.set_mjcb_passive(_body_damping.passive)
    try:
        mujoco.mj_forward(m, d)
        for (u, b), new in zip(inputs, scoped):
            d.ctrl[:8], d.ctrl[8:] = u, b
            mujoco.mj_step(m, d, nstep=plant.substeps)
            mujoco.mj_forward(m, d)
            np.testing.assert_array_equal(np.concatenate([d.qpos, d.qvel, d.sensordata, d.qacc]), new)
    finally:
        mujoco.set_mjcb_passive(None)
    assert np.ptp([x[2] for x in scoped]) > 0.8
    plant.reset()


def test_threads_stepping_plants_at_once_get_the_physics_of_one_thread():
    """Two vessels and a masses plant stepped in three threads at once: each trajectory equals the
    same plant's alone (the callback is installed per call; plants' calls take turns under a lock)."""
    import threading

    def trajectory(plant: Plant, ticks: int) -> np.ndarray:
        u = plant.data.ctrl[plant.actuator_index].copy() * 1.3
        out = []
        for _ in range(ticks):
            plant.step(u)
            out.append(plant.state())
        return np.array(out)

    def plants() -> list[Plant]:
        a, b = Plant(mjcf.get("vessel"), 0.1), Plant(mjcf.get("vessel"), 0.1)
        b.reset({"psi": 1.0, "r": -0.01})
        return [a, b, Plant(mjcf.get("masses"), 0.01)]

    alone = [trajectory(p, 300) for p in plants()]
    together: list = [None] * 3
    threads = [
        threading.Thread(target=lambda i=i, p=p: together.__setitem__(i, trajectory(p, 300)))
        for i, p in enumerate(plants())
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for a, t in zip(alone, together):
        np.testing.assert_array_equal(a, t)
    assert mujoco.get_mjcb_passive() is None


def test_body_damping_declaration_errors_name_the_fix():
    def compile(xml: str) -> mujoco.MjModel:
        return mujoco.MjModel.from_xml_string(xml)

    body = (
        '<worldbody><body><joint name="x" type="slide"/><joint name="y" type="slide" axis="0 1 0"/>'
        '<joint name="psi" type="hinge" axis="0 0 1"/><geom size="1"/></body></worldbody>'
    )
    short = compile(f'<mujoco><custom><numeric name="body_damping" data="1 2 3"/></custom>{body}</mujoco>')
    with pytest.raises(ValueError, match="9"):
        _body_damping.layout(short)
    nojoints = compile(f'<mujoco><custom><numeric name="body_damping" size="9"/></custom>{body}</mujoco>')
    with pytest.raises(ValueError, match="body_damping_joints"):
        _body_damping.layout(nojoints)
    wrong = compile(
        '<mujoco><custom><numeric name="body_damping" size="9"/><text name="body_damping_joints" data="x psi y"/>'
        f"</custom>{body}</mujoco>"
    )
    with pytest.raises(ValueError, match="'psi' is not a slide joint"):
        _body_damping.layout(wrong)
    with pytest.raises(ValueError, match="'psi' is not a slide joint"):
        _body_damping.forces(wrong)


@pytest.mark.parametrize("psi", [0.0, 0.7])
def test_actuator_moment_matrix_is_G_turned_with_the_hull(plant, psi):
    """Thrust columns: [P(ψ) 0; 0 1] G (= G at ψ = 0); disturbance columns: the identity (earth frame)."""
    moment = moment_matrix(plant, at(plant, psi))
    np.testing.assert_allclose(moment[:8].T, vessel.rotation(psi) @ vessel.thruster_matrix(), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(moment[8:], np.eye(3))
    names = [mujoco.mj_id2name(plant.model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(plant.model.nu)]
    assert names == [*vessel.INPUTS, "b_x", "b_y", "b_n"]


def test_linearization_at_rest_is_eq_23(plant):
    """cosim.plant.physics_linear.linearize (MuJoCo finite differences) at ψ = 0, ν = 0, u = 0 gives the paper's A
    and B_u = [0; M⁻¹G]; B_u G⁺ is the paper's B (input τ); C = I₆; E = [0; M⁻¹Pᵀ]."""
    lin = plant.linearize(np.zeros(6), np.zeros(plant.model.nu), continuous=True)
    A, B_tau, B_u, C = vessel.paper_model()
    scale = np.abs(A[3:, 3:]).max()
    np.testing.assert_allclose(lin.A, A, rtol=1e-9, atol=1e-9 * scale)
    np.testing.assert_allclose(lin.B, B_u, rtol=1e-9, atol=1e-9 * np.abs(B_u).max())
    np.testing.assert_allclose(
        lin.B @ np.linalg.pinv(vessel.thruster_matrix()), B_tau, rtol=1e-9, atol=1e-9 * np.abs(B_tau).max()
    )
    np.testing.assert_allclose(lin.C, C, atol=1e-9)
    np.testing.assert_allclose(lin.E, vessel.disturbance_matrix(), rtol=1e-9, atol=1e-9 * np.abs(B_tau).max())
    assert lin.states == ("x", "y", "psi", "x_dot", "y_dot", "r")
    assert lin.inputs == vessel.INPUTS and lin.outputs == ("x", "y", "psi", "u", "v", "r")
    discrete = plant.linearize(np.zeros(6), np.zeros(plant.model.nu))
    Ad, Bd = zoh_discretize(A, B_u, 0.1)
    np.testing.assert_allclose(discrete.A, Ad, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(discrete.B, Bd, rtol=1e-8, atol=1e-9 * np.abs(Bd).max())


def test_keyframe_is_the_papers_initial_state_cruising(plant):
    """η0 = (1, 1, 0), ν0 = (2.2, 1.9, 0) (Sec. 4) with the allocation (4) of τ = D ν0: a cruise."""
    plant.reset()
    np.testing.assert_array_equal(plant.state(), [1.0, 1.0, 0.0, 2.2, 1.9, 0.0])
    np.testing.assert_allclose(plant.sensors(), [1.0, 1.0, 0.0, 2.2, 1.9, 0.0], atol=1e-15)
    u0 = np.linalg.pinv(vessel.thruster_matrix()) @ PAPER_D @ np.array(vessel.INITIAL_NU)
    np.testing.assert_allclose(plant.data.ctrl, [*u0, 0.0, 0.0, 0.0], rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(plant.data.qacc, 0.0, atol=1e-12)


def test_cruise_holds_under_mj_step(plant):
    """100 s of RK4 steps from the keyframe: ν stays ν0 and η = η0 + ν0 t (the damping callback acts
    in every substep: without its ΔD the hull turns away, ψ = −1.3 rad after 100 s)."""
    plant.reset()
    u0 = plant.data.ctrl[:8].copy()
    for _ in range(1000):
        plant.step(u0)
    np.testing.assert_allclose(plant.state(), [1.0 + 220.0, 1.0 + 190.0, 0.0, 2.2, 1.9, 0.0], atol=1e-9)


def test_kinetic_energy_only_decreases_without_thrust(plant):
    """The symmetric part of D dissipates and its skew part does no work: with no input the
    kinetic energy falls at every tick, at any heading."""
    plant.reset({"psi": 2.0, "r": 0.02})
    energy = []
    for _ in range(200):
        plant.step(np.zeros(8))
        energy.append(0.5 * plant.data.qvel @ full_inertia(plant, plant.data) @ plant.data.qvel)
    assert np.all(np.diff(energy) < 0)


def test_sensors_read_body_frame_velocities_at_a_heading(plant):
    psi, nu = 1.1, np.array([2.0, -0.7, 0.03])
    plant.set_state(np.concatenate([[5.0, -3.0, psi], vessel.rotation(psi) @ nu]))
    np.testing.assert_allclose(plant.sensors(), [5.0, -3.0, psi, *nu], rtol=1e-12, atol=1e-12)
    assert not np.allclose(plant.state()[3:], nu)  # the state's velocities are earth-frame
    plant.reset()


def test_disturbance_actuators_are_earth_frame(plant):
    b = np.array([1e5, -2e5, 3e6])
    d = at(plant, 0.9, ctrl=np.concatenate([np.zeros(8), b]))
    np.testing.assert_allclose(d.qfrc_actuator, b)  # generalized force b, i.e. P(ψ)ᵀ b in the body frame


def test_bus_signals_fit_classic_can():
    info = mjcf.get("vessel")
    for channel in (*info.states, *info.sensors, *info.actuators, *info.disturbances):
        assert signal_bits(channel) <= 48, channel.name


def test_disturbance_is_bounded_by_epsilon():
    t = np.arange(0.0, 2000.0, 0.05)
    for seed in range(5):
        b = environment_disturbance(t, seed)
        assert b.shape == (len(t), 3)
        assert np.linalg.norm(b, axis=1).max() <= EnvironmentDisturbance.random(seed).bound <= DISTURBANCE_BOUND
    loud = EnvironmentDisturbance.random(3, current=1e6, wave_force=2e6, wave_moment=3e6)
    assert loud.bound == pytest.approx(1e6 + np.hypot(2e6, 3e6))  # 4.6e6 <= ε
    assert np.linalg.norm(loud(t), axis=1).max() <= DISTURBANCE_BOUND
    with pytest.raises(ValueError, match="lower current, wave_force or wave_moment"):
        EnvironmentDisturbance.random(0, current=2e6, wave_force=3e6, wave_moment=1e6)
    with pytest.raises(ValueError, match="wave_force"):
        EnvironmentDisturbance.random(0, wave_force=-1.0)


def test_disturbance_is_a_current_plus_waves_of_varying_direction():
    t = np.arange(0.0, 4000.0, 0.1)
    model = EnvironmentDisturbance.random(11)
    b = model(t)
    current = np.asarray(model.current)
    assert np.linalg.norm(current) == pytest.approx(2e4)
    np.testing.assert_allclose(b.mean(axis=0), current, atol=2e3)  # the waves average out
    waves = b[:, :2] - current[:2]
    strong = np.linalg.norm(waves, axis=1) > 0.5 * np.max(np.linalg.norm(waves, axis=1))
    axis = np.mod(np.arctan2(waves[strong, 1], waves[strong, 0]), np.pi)  # direction up to sign
    spread = np.ptp(np.unwrap(2 * axis) / 2)
    assert spread > 0.8 * 2 * model.swing  # the wave direction swings by ± 30°
    assert np.std(b[:, 2]) > 1e5  # an oscillating yaw moment


def test_disturbance_is_deterministic_in_the_seed():
    t = np.linspace(0.0, 300.0, 301)
    np.testing.assert_array_equal(environment_disturbance(t, 42), environment_disturbance(t, 42))
    assert not np.allclose(environment_disturbance(t, 42), environment_disturbance(t, 43))
    rng = np.random.default_rng(42)
    first = environment_disturbance(t, rng)
    np.testing.assert_array_equal(environment_disturbance(t, rng), first)  # the Generator is read, not advanced
    np.testing.assert_array_equal(rng.random(), np.random.default_rng(42).random())
    assert environment_disturbance(12.5, 42).shape == (3,)
    np.testing.assert_array_equal(environment_disturbance(12.5, 42), environment_disturbance(np.array([12.5]), 42)[0])


def test_the_batched_disturbance_of_k_seas_is_each_seas_bit_for_bit():
    seas = [
        EnvironmentDisturbance.random(seed, current=c, wave_force=f, wave_moment=m)
        for seed, (c, f, m) in enumerate([(2e4, 1e5, 1e6), (0.0, 0.0, 0.0), (144.0, 108.0, 108.0), (4e4, 3e5, 2e6)])
    ]
    b = EnvironmentDisturbance.batched(seas)
    assert b is not None
    for t in [0.0, 0.1, 12.5, 299.99, 1234.567, -3.0]:
        found = b(t)
        assert found.shape == (len(seas), 3)
        for row, sea in zip(found, seas):
            np.testing.assert_array_equal(row, sea(t))  # exactly: a batch's runs step as alone
    other = EnvironmentDisturbance.random(5, components=4)
    assert EnvironmentDisturbance.batched([seas[0], other]) is None  # another number of components: each alone
