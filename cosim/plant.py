"""A MuJoCo plant sampled at the scenario's tick, and its linearization from MuJoCo itself.

The dynamics come from ``mj_step`` only. The state is MuJoCo's [qpos, qvel, act]; the plant
module (``mjcf/<plant>.py``) names its components, the sensors and the actuators.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from cosim.errors import ModelError
from estimators.design import zoh_discretize
from estimators.model import LinearModel
from mjcf import PlantInfo

#: Finite-difference step for linearization: a power of two, so that perturbing a coordinate that
#: is 0 (or any value whose last bits are clear) and differencing are exact in floating point.
FD_STEP = 2.0**-20


class Plant:
    """One MuJoCo simulation of a plant, advanced ``sample_time`` seconds per tick.

    ``sensors`` selects and orders the transmitted sensors (default: all the plant declares).
    """

    def __init__(self, info: PlantInfo, sample_time: float, sensors: Sequence[str] | None = None) -> None:
        self.info = info
        self.model = load_model(info)
        self.data = mujoco.MjData(self.model)
        self.sample_time = float(sample_time)
        self.substeps = substeps(self.sample_time, self.model.opt.timestep, info.model_file)
        self.sensor_names = tuple(sensors) if sensors is not None else tuple(s.name for s in info.sensors)
        self.sensor_index = np.array([sensor_address(self.model, info, name) for name in self.sensor_names], dtype=int)
        self.actuator_names = tuple(a.name for a in info.actuators)
        self.disturbance_names = tuple(d.name for d in info.disturbances)
        self._known = actuator_ids(self.model, self.actuator_names)
        self._unknown = actuator_ids(self.model, self.disturbance_names)
        self.state_names = tuple(s.name for s in info.states)
        self.reset()

    @property
    def nx(self) -> int:
        return self.model.nq + self.model.nv + self.model.na

    @property
    def time(self) -> float:
        return float(self.data.time)

    def reset(self, initial: dict[str, float] | None = None) -> None:
        """Back to the plant's keyframe, then override the named state components."""
        key = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_KEY, self.info.keyframe)
        if key < 0:
            raise ModelError(f"{self.info.model_file}: no keyframe named {self.info.keyframe!r}; add <key name=\"{self.info.keyframe}\"/>")
        mujoco.mj_resetDataKeyframe(self.model, self.data, key)
        if initial:
            x = self.state()
            for name, value in initial.items():
                x[self.state_names.index(name)] = value
            self.set_state(x)
        mujoco.mj_forward(self.model, self.data)

    def state(self) -> np.ndarray:
        """[qpos, qvel, act], a copy."""
        return np.concatenate([self.data.qpos, self.data.qvel, self.data.act])

    def set_state(self, x: np.ndarray) -> None:
        m = self.model
        self.data.qpos[:] = x[: m.nq]
        self.data.qvel[:] = x[m.nq : m.nq + m.nv]
        self.data.act[:] = x[m.nq + m.nv :]
        mujoco.mj_forward(m, self.data)

    def sensors(self) -> np.ndarray:
        """The selected sensors' true readings at the current state, a copy."""
        return self.data.sensordata[self.sensor_index]

    def step(self, ctrl: np.ndarray, disturbance: np.ndarray | None = None) -> None:
        """Hold the known inputs ``ctrl`` and the unknown inputs ``disturbance`` (default 0) for
        one sample time (zero-order hold) and advance the physics."""
        self.data.ctrl[self._known] = ctrl
        self.data.ctrl[self._unknown] = 0.0 if disturbance is None else disturbance
        mujoco.mj_step(self.model, self.data, nstep=self.substeps)
        # mj_step leaves sensordata at the state before its last integration; refresh it.
        mujoco.mj_forward(self.model, self.data)

    def linearize(
        self, x: np.ndarray | None = None, u: np.ndarray | None = None, *, continuous: bool = False, method: str = "zoh"
    ) -> LinearModel:
        """The plant linearized at (x, u) (default: the current state and ctrl), in discrete time at
        the sample time or in continuous time; see ``linearize``."""
        return linearize(self, x, u, dt=None if continuous else self.sample_time, method=method)


def load_model(info: PlantInfo) -> mujoco.MjModel:
    """Compile the plant's MJCF, checking that it has what the plant module declares."""
    try:
        model = mujoco.MjModel.from_xml_path(str(info.model_path))
    except ValueError as error:
        raise ModelError(f"{info.model_path}: MuJoCo could not compile the model: {error}") from None
    nstate = model.nq + model.nv + model.na
    if len(info.states) != nstate:
        raise ModelError(
            f"{info.model_file}: plant module names {len(info.states)} states but the model has "
            f"nq + nv + na = {nstate}; list one name per component of [qpos, qvel, act]"
        )
    for actuator in (*info.actuators, *info.disturbances):
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, actuator.name) < 0:
            raise ModelError(f"{info.model_file}: no actuator named {actuator.name!r} (declared by the plant module)")
    declared = len(info.actuators) + len(info.disturbances)
    if declared != model.nu:
        raise ModelError(f"{info.model_file}: the model has {model.nu} actuators, the plant module names {declared} (inputs and disturbances)")
    for sensor in info.sensors:
        sensor_address(model, info, sensor.name)
    return model


def actuator_ids(model: mujoco.MjModel, names: Sequence[str]) -> np.ndarray:
    """Indices in ``ctrl`` of the named actuators."""
    return np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name) for name in names], dtype=int)


def sensor_address(model: mujoco.MjModel, info: PlantInfo, name: str) -> int:
    """Index of a scalar sensor in ``sensordata``."""
    info.sensor(name)  # declared by the plant module (KeyError lists the known ones)
    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)
    if sid < 0:
        raise ModelError(f"{info.model_file}: no sensor named {name!r} (declared by the plant module)")
    if model.sensor_dim[sid] != 1:
        raise ModelError(f"{info.model_file}: sensor {name!r} has {model.sensor_dim[sid]} components; use scalar sensors")
    return int(model.sensor_adr[sid])


def substeps(sample_time: float, timestep: float, where: str) -> int:
    """Physics steps per tick; the sample time must be a whole number of MuJoCo timesteps."""
    n = round(sample_time / timestep)
    if n < 1 or abs(n * timestep - sample_time) > 1e-9 * sample_time:
        raise ModelError(
            f"sample_time = {sample_time} s is not a whole multiple of the timestep {timestep} s of {where}; "
            f"choose a multiple such as {max(n, 1) * timestep:g} s"
        )
    return n


def linearize(
    plant: Plant, x: np.ndarray | None = None, u: np.ndarray | None = None, *, dt: float | None, method: str = "zoh"
) -> LinearModel:
    """Linearize a MuJoCo plant at the operating point (x, u), from MuJoCo itself.

    The continuous-time Jacobians ∂ẋ/∂x, ∂ẋ/∂u (with ẋ = [qvel, qacc, act_dot] from
    ``mj_forward``; disturbance actuators give the columns of E) and the sensor Jacobians C = ∂y/∂x, D = ∂y/∂u are central finite differences in
    MuJoCo's tangent space (positions perturbed with ``mj_integratePos``, so ball and free joints
    are handled). Then, with ``dt`` given:

    - ``method="zoh"``: exact zero-order-hold discretization A = exp(A_c dt),
      B = ∫₀^dt exp(A_c s) ds B_c — the discrete model of the linearized physics, as the papers use;
    - ``method="step"``: central differences of the simulator's own step over dt (``mj_step`` with
      the model's integrator and substeps), i.e. the linearization of what the simulation does.

    ``mjd_transitionFD`` is not used: it refuses RK4 and is first order with Euler. For a linear
    plant both methods agree with the exact discretization to ~1e-10 (FD rounding), and C is exact.
    With ``dt=None`` the continuous-time model is returned.
    """
    m = plant.model
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:], d.act[:], d.ctrl[:] = plant.data.qpos, plant.data.qvel, plant.data.act, plant.data.ctrl
    if x is not None:
        d.qpos[:] = x[: m.nq]
        d.qvel[:] = x[m.nq : m.nq + m.nv]
        d.act[:] = x[m.nq + m.nv :]
    if u is not None:
        d.ctrl[:] = u
    qpos0, qvel0, act0, ctrl0 = d.qpos.copy(), d.qvel.copy(), d.act.copy(), d.ctrl.copy()
    sensors = plant.sensor_index
    nv, na, nu = m.nv, m.na, m.nu
    ndx = 2 * nv + na

    def set_point(dx: np.ndarray, du: np.ndarray) -> None:
        d.qpos[:] = qpos0
        mujoco.mj_integratePos(m, d.qpos, dx[:nv], 1.0)
        d.qvel[:] = qvel0 + dx[nv : 2 * nv]
        d.act[:] = act0 + dx[2 * nv :]
        d.ctrl[:] = ctrl0 + du
        d.time = 0.0

    def continuous(dx: np.ndarray, du: np.ndarray) -> np.ndarray:
        set_point(dx, du)
        mujoco.mj_forward(m, d)
        return np.concatenate([d.qvel, d.qacc, d.act_dot, d.sensordata[sensors]])

    def stepped(dx: np.ndarray, du: np.ndarray) -> np.ndarray:
        set_point(dx, du)
        mujoco.mj_forward(m, d)
        y = d.sensordata[sensors].copy()
        mujoco.mj_step(m, d, nstep=substeps(dt, m.opt.timestep, plant.info.model_file))
        dq = np.zeros(nv)
        mujoco.mj_differentiatePos(m, dq, 1.0, qpos0, d.qpos)
        return np.concatenate([dq, d.qvel - qvel0, d.act - act0, y])

    if method not in ("zoh", "step"):
        raise ValueError(f"unknown linearization method {method!r}; use 'zoh' or 'step'")
    f = stepped if method == "step" and dt is not None else continuous
    jac_x = _central_difference(lambda dx: f(dx, np.zeros(nu)), ndx)
    jac_u = _central_difference(lambda du: f(np.zeros(ndx), du), nu)
    A, BE = jac_x[:ndx], jac_u[:ndx]
    C, D = jac_x[ndx:], jac_u[ndx:, plant._known]
    if f is continuous and dt is not None:
        A, BE = zoh_discretize(A, BE, dt)
    B, E = BE[:, plant._known], BE[:, plant._unknown]
    set_point(np.zeros(ndx), np.zeros(nu))
    mujoco.mj_forward(m, d)
    state_names = plant.state_names if len(plant.state_names) == ndx else tuple(f"dx{i}" for i in range(ndx))
    return LinearModel(
        A, B, C, D, dt, state_names, plant.actuator_names, plant.sensor_names,
        x_op=np.concatenate([qpos0, qvel0, act0]) if m.nq == nv else None,
        u_op=ctrl0[plant._known], y_op=d.sensordata[sensors].copy(), E=E, disturbances=plant.disturbance_names,
    )


def _central_difference(f, size: int) -> np.ndarray:
    """∂f/∂v at v = 0 by central differences, shape (len(f(0)), size)."""
    if size == 0:
        return np.zeros((len(f(np.zeros(0))), 0))
    columns = []
    for i in range(size):
        e = np.zeros(size)
        e[i] = FD_STEP
        columns.append((f(e) - f(-e)) / (2.0 * FD_STEP))
    return np.array(columns).T
