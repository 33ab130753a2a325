"""A MuJoCo plant linearized from MuJoCo itself: central differences of its dynamics in MuJoCo's
tangent space (``_linearize_joint_state``), or of the quasi-static flows of a tendon-state plant
(``_linearize_tendon_state``), at its operating point; where that point is no equilibrium of its
inputs, with the drift ``cosim.plant.equilibrium`` decides on (``PlantInfo.drift_left_out``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any, Protocol

import mujoco
import numpy as np

from cosim.errors import ModelError
from cosim.plant import equilibrium
from cosim.plant.mujoco_model import FD_STEP, quasi_static_velocities, substeps
from estimators.design import zoh_discretize
from estimators.model import LinearModel
from mjcf import PlantInfo

#: Relative size of the length steps in the linearization of a tendon-state plant (× FD_STEP).
H_STEP = 2.0**10


def linearize(
    plant: MujocoPlant,
    x: np.ndarray | None = None,
    u: np.ndarray | None = None,
    *,
    dt: float | None,
    method: str = "zoh",
) -> LinearModel:
    """Linearize a MuJoCo plant at the operating point (x, u), from MuJoCo itself.

    The continuous-time Jacobians ∂ẋ/∂x, ∂ẋ/∂u (with ẋ = [qvel, qacc, act_dot] from
    ``mj_forward``; disturbance actuators give the columns of E) and the sensor Jacobians
    C = ∂y/∂x, D = ∂y/∂u are central finite differences in MuJoCo's tangent space (positions
    perturbed with ``mj_integratePos``, so ball and free joints are handled). Then, with ``dt`` given:

    - ``method="zoh"``: exact zero-order-hold discretization A = exp(A_c dt),
      B = ∫₀^dt exp(A_c s) ds B_c — the discrete model of the linearized physics, as the papers use;
    - ``method="step"``: central differences of the simulator's own step over dt (``mj_step`` with
      the model's integrator and substeps), i.e. the linearization of what the simulation does.

    ``mjd_transitionFD`` is not used: it refuses RK4 and is first order with Euler. For a linear
    plant both methods agree with the exact discretization to ~1e-10 (FD rounding), and C is exact.
    With ``dt=None`` the continuous-time model is returned.

    A plant with state tendons (``PlantInfo.state_tendons``) is linearized in those lengths, x = h:
    see ``_linearize_tendon_state``.
    """
    if method not in ("zoh", "step"):
        raise ValueError(f"unknown linearization method {method!r}; use 'zoh' or 'step'")
    with plant.physics():
        if plant.tendons is not None:
            return _linearize_tendon_state(plant, x, u, dt=dt, method=method)
        return _linearize_joint_state(plant, x, u, dt=dt, method=method)


class MujocoPlant(Protocol):
    """What the linearization reads of a sampled MuJoCo plant (``cosim.plant.physics.Plant``), and
    ``operating_point``, which it sets (``cosim.plant.equilibrium.declared``)."""

    info: PlantInfo
    model: mujoco.MjModel
    data: mujoco.MjData
    sensor_index: np.ndarray
    sensor_zero: np.ndarray
    actuator_index: np.ndarray
    disturbance_index: np.ndarray
    tendons: np.ndarray | None
    tendons_pinv: np.ndarray | None
    state_names: tuple[str, ...]
    actuator_names: tuple[str, ...]
    sensor_names: tuple[str, ...]
    disturbance_names: tuple[str, ...]
    operating_point: str

    def physics(self) -> contextlib.AbstractContextManager[Any]: ...


class _JointPoint:
    """A copy of the plant's data at the point (x, u) of its joint state [qpos, qvel, act], moved
    from there along MuJoCo's tangent space (positions with ``mj_integratePos``)."""

    def __init__(self, plant: MujocoPlant, x: np.ndarray | None, u: np.ndarray | None, dt: float | None) -> None:
        m = self.model = plant.model
        d = self.data = mujoco.MjData(m)
        d.qpos[:], d.qvel[:], d.act[:], d.ctrl[:] = plant.data.qpos, plant.data.qvel, plant.data.act, plant.data.ctrl
        if x is not None:
            d.qpos[:] = x[: m.nq]
            d.qvel[:] = x[m.nq : m.nq + m.nv]
            d.act[:] = x[m.nq + m.nv :]
        if u is not None:
            d.ctrl[:] = u
        self.qpos, self.qvel, self.act, self.ctrl = d.qpos.copy(), d.qvel.copy(), d.act.copy(), d.ctrl.copy()
        self.sensors = plant.sensor_index
        self.ndx = 2 * m.nv + m.na
        self.nstep = substeps(dt, m.opt.timestep, plant.info.model_file) if dt is not None else 0

    def _set(self, dx: np.ndarray, du: np.ndarray) -> None:
        m, d, nv = self.model, self.data, self.model.nv
        d.qpos[:] = self.qpos
        mujoco.mj_integratePos(m, d.qpos, dx[:nv], 1.0)
        d.qvel[:] = self.qvel + dx[nv : 2 * nv]
        d.act[:] = self.act + dx[2 * nv :]
        d.ctrl[:] = self.ctrl + du
        d.time = 0.0

    def continuous(self, dx: np.ndarray, du: np.ndarray) -> np.ndarray:
        """ẋ and the sensors at the point moved by (dx, du)."""
        m, d = self.model, self.data
        self._set(dx, du)
        mujoco.mj_forward(m, d)
        return np.concatenate([d.qvel, d.qacc, d.act_dot, d.sensordata[self.sensors]])

    def stepped(self, dx: np.ndarray, du: np.ndarray) -> np.ndarray:
        """The change of the state over one simulated step from the point moved by (dx, du), and the
        sensors there."""
        m, d = self.model, self.data
        self._set(dx, du)
        mujoco.mj_forward(m, d)
        y = d.sensordata[self.sensors].copy()
        mujoco.mj_step(m, d, nstep=self.nstep)
        dq = np.zeros(m.nv)
        mujoco.mj_differentiatePos(m, dq, 1.0, self.qpos, d.qpos)
        return np.concatenate([dq, d.qvel - self.qvel, d.act - self.act, y])


def _linearize_joint_state(
    plant: MujocoPlant, x: np.ndarray | None, u: np.ndarray | None, *, dt: float | None, method: str
) -> LinearModel:
    """``linearize`` of a plant whose state is [qpos, qvel, act]."""
    point = _JointPoint(plant, x, u, dt)
    m, ndx, nu = plant.model, point.ndx, plant.model.nu
    stepped = method == "step" and dt is not None
    f = point.stepped if stepped else point.continuous
    jac_x = _central_difference(lambda dx: f(dx, np.zeros(nu)), ndx)
    jac_u = _central_difference(lambda du: f(np.zeros(ndx), du), nu)
    A, BE = jac_x[:ndx], jac_u[:ndx]
    C, D = jac_x[ndx:], jac_u[ndx:, plant.actuator_index]
    if not stepped and dt is not None:
        A, BE = zoh_discretize(A, BE, dt)
    at = f(np.zeros(ndx), np.zeros(nu))  # ẋ at the point (or its change over one step), and the sensors
    x_op = np.concatenate([point.qpos, point.qvel, point.act]) if m.nq == m.nv else None
    drift = equilibrium.declared(plant, at[:ndx], jac_x[:ndx], jac_u[:ndx], x_op, point.ctrl, dt, stepped=stepped)
    state_names = plant.state_names if len(plant.state_names) == ndx else tuple(f"dx{i}" for i in range(ndx))
    return _linear_model(plant, (A, BE, C, D), dt, state_names, (x_op, point.ctrl, at[ndx:]), drift)


def _linear_model(
    plant: MujocoPlant,
    matrices: tuple[np.ndarray, ...],
    dt: float | None,
    state_names: tuple[str, ...],
    point: tuple[np.ndarray | None, np.ndarray, np.ndarray],
    drift: np.ndarray | None,
) -> LinearModel:
    """The model of ``matrices`` = (A, [B E], C, D) about ``point`` = (x, every actuator's ctrl,
    the sensors' readings there)."""
    A, BE, C, D = matrices
    x_op, ctrl, y = point
    return LinearModel(
        A,
        BE[:, plant.actuator_index],
        C,
        D,
        dt,
        state_names,
        plant.actuator_names,
        plant.sensor_names,
        x_op=x_op,
        u_op=ctrl[plant.actuator_index],
        y_op=y - plant.sensor_zero,
        E=BE[:, plant.disturbance_index],
        disturbances=plant.disturbance_names,
        drift=drift,
    )


def _linearize_tendon_state(
    plant: MujocoPlant, x: np.ndarray | None, u: np.ndarray | None, *, dt: float | None, method: str
) -> LinearModel:
    """Linearization in the state tendons' lengths h = T qpos, the other coordinates eliminated.

    The joint velocities v are fast: they settle (within ~1 ms for the three-tank flows) to the
    values v*(h, u) where the smooth forces balance, f(h, v*, u) = 0 (``quasi_static_velocities``),
    and ḣ = T v. This is the singular-perturbation (quasi-static) limit of MuJoCo's dynamics, the
    limit of a vanishing inertance, which is exactly the paper's model (57):

        A_c = T ∂v*/∂h = −T f_v⁻¹ f_h,   [B_c E_c] = −T f_v⁻¹ f_u,
        C = y_h + y_v ∂v*/∂h,   D = y_u + y_v ∂v*/∂u,

    with f = ``qfrc_smooth`` (integrator-independent, unlike qacc under the ``discrete``
    integrator) and central differences: positions moved along T⁺ (changing h only), velocities by
    relative steps (exact for the quadratic orifice loss). The slow invariant subspace of the full
    linearization [qpos, qvel] would instead keep the inertance's O(τ_fast/τ_slow) corrections
    (its slow eigenvalues differ by < 1e-5 relative for the three-tank system,
    tests/test_three_tank.py); that is a numerical device's footprint, not the paper's model, so it
    is left out. f_v must be invertible: a flow at zero head (where Torricelli's law has an infinite
    slope) cannot be linearized.

    ``method="zoh"`` discretizes (A_c, B_c, E_c) exactly; ``method="step"`` differentiates the
    simulation itself over dt (levels perturbed, velocities quasi-steady, ``mj_step``).
    Control clamping is off while differencing (a pump linearized at zero flow).
    """
    m, T, T_pinv = plant.model, plant.tendons, plant.tendons_pinv
    assert T is not None and T_pinv is not None
    d = mujoco.MjData(m)
    d.qpos[:], d.ctrl[:], d.qvel[:] = plant.data.qpos, plant.data.ctrl, plant.data.qvel
    if u is not None:
        d.ctrl[:] = u
    if x is not None:
        d.qpos[:] += T_pinv @ (np.asarray(x, dtype=float) - T @ d.qpos)
    flags = m.opt.disableflags
    m.opt.disableflags = flags | mujoco.mjtDisableBit.mjDSBL_CLAMPCTRL
    try:
        d.qvel[:] = quasi_static_velocities(m, d)
        point = d.qpos.copy(), d.qvel.copy(), d.ctrl.copy()
        qpos0, qvel0, ctrl0 = point
        A, BE, C, D = _quasi_static_jacobians(plant, d, point)
        h0 = T @ qpos0
        drift = equilibrium.declared(plant, T @ qvel0, A, BE, h0, ctrl0, dt)  # ḣ = T v* at the point
        if dt is not None and method == "step":
            A, BE = _stepped_tendon_model(plant, d, point, dt)
        elif dt is not None:
            A, BE = zoh_discretize(A, BE, dt)
        d.qpos[:], d.qvel[:], d.ctrl[:] = qpos0, qvel0, ctrl0
        mujoco.mj_forward(m, d)
        y0 = d.sensordata[plant.sensor_index].copy()
    finally:
        m.opt.disableflags = flags
    return _linear_model(plant, (A, BE, C, D), dt, plant.state_names, (h0, ctrl0, y0), drift)


def _quasi_static_jacobians(
    plant: MujocoPlant, d: mujoco.MjData, point: tuple[np.ndarray, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(A_c, [B_c E_c], C, D) of a tendon-state plant at ``point`` = (qpos, qvel, ctrl), its
    velocities quasi-steady there: see ``_linearize_tendon_state``."""
    m, T, T_pinv = plant.model, plant.tendons, plant.tendons_pinv
    assert T is not None and T_pinv is not None
    qpos0, qvel0, ctrl0 = point
    sensors, ns, nv, nu = plant.sensor_index, T.shape[0], m.nv, m.nu

    def forces(dh: np.ndarray, dv: np.ndarray, du: np.ndarray) -> np.ndarray:
        d.qpos[:], d.qvel[:], d.ctrl[:] = qpos0 + T_pinv @ dh, qvel0 + dv, ctrl0 + du
        mujoco.mj_forward(m, d)
        return np.concatenate([d.qfrc_smooth, d.sensordata[sensors]])

    vscale = np.maximum(np.abs(qvel0), 1e-3 * max(np.max(np.abs(qvel0)), FD_STEP))  # relative steps
    zs, zv, zu = np.zeros(ns), np.zeros(nv), np.zeros(nu)
    # Lengths are sums of large coordinates: a step of 2⁻¹⁰ length units keeps qpos rounding out
    # of the differences (tendon springs and gauges are linear in the lengths).
    jac_h = _central_difference(lambda dh: forces(dh * H_STEP, zv, zu), ns) / H_STEP
    jac_v = _central_difference(lambda dv: forces(zs, dv * vscale, zu), nv) / vscale
    jac_u = _central_difference(lambda du: forces(zs, zv, du), nu)
    _require_tendon_state(plant, d, point, jac_h[:nv])
    f_v = jac_v[:nv]
    if np.linalg.cond(f_v) > 1e12:
        raise ModelError(
            f"{plant.info.model_file}: cannot eliminate the velocities at this point (a flow at zero head?)"
        )
    dv_dh = -np.linalg.solve(f_v, jac_h[:nv])
    dv_du = -np.linalg.solve(f_v, jac_u[:nv])
    C = jac_h[nv:] + jac_v[nv:] @ dv_dh
    D = (jac_u[nv:] + jac_v[nv:] @ dv_du)[:, plant.actuator_index]
    return T @ dv_dh, T @ dv_du, C, D


def _require_tendon_state(plant: MujocoPlant, d: mujoco.MjData, point: tuple[np.ndarray, ...], f_h: np.ndarray) -> None:
    """Positions off the state tendons (the null space of T) must not change the forces, or the
    tendon lengths h are not a state; ``f_h`` is ∂f/∂h at ``point`` = (qpos, qvel, ctrl)."""
    m, T, T_pinv = plant.model, plant.tendons, plant.tendons_pinv
    assert T is not None and T_pinv is not None
    qpos0, qvel0, ctrl0 = point
    null = np.linalg.svd(T)[2][T.shape[0] :].T * np.abs(T_pinv).max()  # moves as large as T⁺'s
    if not null.size:
        return

    def moved(dq: np.ndarray) -> np.ndarray:
        d.qpos[:], d.qvel[:], d.ctrl[:] = qpos0 + null @ dq, qvel0, ctrl0
        mujoco.mj_forward(m, d)
        return d.qfrc_smooth.copy()

    if np.abs(_central_difference(moved, null.shape[1])).max() > 1e-6 * np.abs(f_h).max():  # > FD rounding
        raise ModelError(f"{plant.info.model_file}: forces depend on coordinates other than the state tendons")


def _stepped_tendon_model(
    plant: MujocoPlant, d: mujoco.MjData, point: tuple[np.ndarray, ...], dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """(A, [B E]) of the simulation itself over dt about ``point`` = (qpos, qvel, ctrl): levels
    perturbed, velocities quasi-steady, ``mj_step``."""
    m, T, T_pinv = plant.model, plant.tendons, plant.tendons_pinv
    assert T is not None and T_pinv is not None
    qpos0, qvel0, ctrl0 = point
    nstep = substeps(dt, m.opt.timestep, plant.info.model_file)

    def stepped(dh: np.ndarray, du: np.ndarray) -> np.ndarray:
        d.qpos[:], d.ctrl[:], d.qvel[:], d.time = qpos0 + T_pinv @ dh, ctrl0 + du, qvel0, 0.0
        d.qvel[:] = quasi_static_velocities(m, d)
        mujoco.mj_step(m, d, nstep=nstep)
        return T @ d.qpos

    zs, zu = np.zeros(T.shape[0]), np.zeros(m.nu)
    A = _central_difference(lambda dh: stepped(dh * H_STEP, zu), T.shape[0]) / H_STEP
    return A, _central_difference(lambda du: stepped(zs, du), m.nu)


def _central_difference(f: Callable[[np.ndarray], np.ndarray], size: int) -> np.ndarray:
    """∂f/∂v at v = 0 by central differences, shape (len(f(0)), size)."""
    if size == 0:
        return np.zeros((len(f(np.zeros(0))), 0))
    columns = []
    for i in range(size):
        e = np.zeros(size)
        e[i] = FD_STEP
        columns.append((f(e) - f(-e)) / (2.0 * FD_STEP))
    return np.array(columns).T
