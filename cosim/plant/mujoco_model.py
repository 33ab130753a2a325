"""The compiled MuJoCo model of a plant and the calls on it that the sampled plant
(``cosim.plant.physics``) and its linearization (``cosim.plant.physics_linear``) share: compiling
it (``load_model``, checked against its ``PlantInfo``), its actuators', sensors' and state
tendons' places, the sub-steps of a sample time, the quasi-static velocities of a tendon-state
plant, and the passive forces its MJCF cannot express (``PassiveForces``: see
``cosim.plant.physics`` for why they are installed per call).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from typing import Any

import mujoco
import numpy as np

from cosim.errors import ModelError
from mjcf import PlantInfo

#: Finite-difference step for linearization: a power of two, so that perturbing a coordinate that
#: is 0 (or any value whose last bits are clear) and differencing are exact in floating point.
FD_STEP = 2.0**-20

#: Held by every MuJoCo call of a plant (``Plant.physics``), by a ``PassiveForces`` block, and while
#: ``load_model`` compiles (which must run with no Python callback installed): plants in several
#: threads take turns. Not only for plants with passive forces: a call that reads MuJoCo's callback
#: pointer while another thread puts the previous callback back would find the bindings' Python
#: callback gone ("py_mjcb_passive is null"). Hold it around your own MuJoCo calls in other
#: threads while plants run.
CALLBACKS = threading.RLock()


class PassiveForces:
    """A model's passive-force function installed as ``mjcb_passive`` for a ``with`` block only.

    MuJoCo calls ``mjcb_passive`` in every ``mj_passive`` (each ``mj_forward``, each RK4 stage of
    ``mj_step``), for every model in the process. ``force`` (``PlantInfo.passive_forces``) applies
    to ``model`` (any MjData of it) and leaves other models alone. Entering the block (under
    ``CALLBACKS``) installs it, or, if another callback was installed, one that hands every other
    model to that one; leaving the block, also by an exception, puts the previous callback back.
    Blocks nest (the same plant's, another plant's). Code outside this module that installs its own
    Python ``mjcb_passive`` owns that state; while it is installed, compiling a model elsewhere than
    ``load_model`` fails (MuJoCo calls it before the model has a Python object).
    """

    def __init__(self, model: mujoco.MjModel, force: Callable[[Any, Any], None]) -> None:
        self.model = model
        self.force = force
        outer: list[Any] = []  # the callbacks found on entering, innermost last
        self._outer = outer

        def chained(m: mujoco.MjModel, d: mujoco.MjData) -> None:
            if m is model:
                force(m, d)
            else:
                outer[0](m, d)

        self._chained = chained

    def __enter__(self) -> PassiveForces:
        CALLBACKS.acquire()
        try:
            current = mujoco.get_mjcb_passive()
            if current is None:
                mujoco.set_mjcb_passive(self.force)
            elif current is not self.force and current is not self._chained:
                mujoco.set_mjcb_passive(self._chained)
            self._outer.append(current)
        except BaseException:
            CALLBACKS.release()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            previous = self._outer.pop()
            if previous is not self.force and previous is not self._chained:
                mujoco.set_mjcb_passive(previous)
        finally:
            CALLBACKS.release()


def passive_forces(model: mujoco.MjModel, info: PlantInfo) -> PassiveForces | None:
    """The plant's extra passive forces for this compiled model (None if it has none)."""
    if info.passive_forces is None:
        return None
    try:
        force = info.passive_forces(model)
    except ValueError as error:
        raise ModelError(f"{info.model_file}: {error}") from None
    return None if force is None else PassiveForces(model, force)


def load_model(info: PlantInfo) -> mujoco.MjModel:
    """Compile the plant's MJCF, checking that it has what the plant module declares.

    Installs nothing: the plant's passive forces are ``passive_forces``' business, per call."""
    # The compiler runs mj_passive before the model has a Python object, so a Python mjcb_passive
    # installed by someone else would make it fail: compile without one, then put it back.
    with CALLBACKS:
        outer = mujoco.get_mjcb_passive()
        if outer is not None:
            mujoco.set_mjcb_passive(None)
        try:
            model = mujoco.MjModel.from_xml_path(str(info.model_path))
        except ValueError as error:
            raise ModelError(f"{info.model_path}: MuJoCo could not compile the model: {error}") from None
        finally:
            if outer is not None:
                mujoco.set_mjcb_passive(outer)
    _check_states(model, info)
    for actuator in (*info.actuators, *info.disturbances):
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, actuator.name) < 0:
            raise ModelError(f"{info.model_file}: no actuator named {actuator.name!r} (declared by the plant module)")
    declared = len(info.actuators) + len(info.disturbances)
    if declared != model.nu:
        raise ModelError(
            f"{info.model_file}: the model has {model.nu} actuators, the plant module names {declared} "
            "(inputs and disturbances)"
        )
    for sensor in info.sensors:
        sensor_address(model, info, sensor.name)
    return model


def _check_states(model: mujoco.MjModel, info: PlantInfo) -> None:
    if info.state_tendons:
        if len(info.states) != len(info.state_tendons):
            raise ModelError(
                f"{info.model_file}: plant module names {len(info.states)} states but "
                f"{len(info.state_tendons)} state tendons"
            )
        return
    nstate = model.nq + model.nv + model.na
    if len(info.states) != nstate:
        raise ModelError(
            f"{info.model_file}: plant module names {len(info.states)} states but the model has "
            f"nq + nv + na = {nstate}; list one name per component of [qpos, qvel, act]"
        )


def state_tendon_matrix(model: mujoco.MjModel, info: PlantInfo) -> np.ndarray | None:
    """T with the state tendons' lengths = T @ qpos (None if the plant declares none).

    The state tendons must be fixed tendons (constant coefficients over joints), independent, in a
    model of scalar joints (hinge and slide, so qpos and qvel have the same coordinates) with no
    actuator activations.
    """
    if not info.state_tendons:
        return None
    where = info.model_file
    if model.nq != model.nv or model.na:
        raise ModelError(f"{where}: state tendons need a model of hinge and slide joints without actuator activations")
    T = np.zeros((len(info.state_tendons), model.nv))
    for row, name in enumerate(info.state_tendons):
        tid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TENDON, name)
        if tid < 0:
            raise ModelError(f"{where}: no tendon named {name!r} (a state tendon of the plant module)")
        for w in range(model.tendon_adr[tid], model.tendon_adr[tid] + model.tendon_num[tid]):
            if model.wrap_type[w] != mujoco.mjtWrap.mjWRAP_JOINT:
                raise ModelError(f"{where}: state tendon {name!r} is not a fixed tendon")
            T[row, model.jnt_dofadr[model.wrap_objid[w]]] += model.wrap_prm[w]
    if np.linalg.matrix_rank(T) < len(info.state_tendons):
        raise ModelError(f"{where}: the state tendons {', '.join(info.state_tendons)} are not independent")
    return T


def quasi_static_velocities(model: mujoco.MjModel, data: mujoco.MjData, max_iter: int = 200) -> np.ndarray:
    """The joint velocities at which the smooth forces balance (``qfrc_smooth`` = 0, so the
    unconstrained acceleration is 0) at data's positions, ctrl and act: the flows' quasi-steady
    values (Torricelli). Newton's method from ``data.qvel`` with central-difference Jacobians;
    ``data`` is not changed. Constraint forces (e.g. level limits) play no part.
    """
    d = mujoco.MjData(model)
    d.qpos[:], d.act[:], d.ctrl[:] = data.qpos, data.act, data.ctrl

    def force(v: np.ndarray) -> np.ndarray:
        d.qvel[:] = v
        mujoco.mj_forward(model, d)
        return d.qfrc_smooth.copy()

    v = data.qvel.copy()
    for _ in range(max_iter):
        f = force(v)
        scale = max(np.max(np.abs(v)), FD_STEP)
        # Relative steps keep an odd-quadratic loss q|q| differenced exactly (no sign change).
        steps = FD_STEP * np.maximum(np.abs(v), 1e-3 * scale)
        J = np.array([(force(v + s * e) - force(v - s * e)) / (2.0 * s) for s, e in zip(steps, np.eye(len(v)))]).T
        try:
            dv = np.linalg.solve(J, -f)
        except np.linalg.LinAlgError:
            raise ModelError(
                "no quasi-steady velocities: every joint of a tendon-state plant needs a velocity-dependent "
                "force (damping, a velocity servo)"
            ) from None
        v = v + dv
        if np.max(np.abs(dv), initial=0.0) <= 1e-13 * scale:
            return v
    raise ModelError(f"no quasi-steady velocities: Newton's method did not converge in {max_iter} iterations")


def actuator_ids(model: mujoco.MjModel, names: Sequence[str]) -> np.ndarray:
    """Indices in ``ctrl`` of the named actuators."""
    return np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name) for name in names], dtype=int)


def sensor_address(model: mujoco.MjModel, info: PlantInfo, name: str) -> int:
    """Index in ``sensordata`` of a scalar sensor, or of the channel's component of a vector sensor."""
    channel = info.sensor(name)  # declared by the plant module (KeyError lists the known ones)
    name = channel.source or name
    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)
    if sid < 0:
        raise ModelError(f"{info.model_file}: no sensor named {name!r} (declared by the plant module)")
    dim = int(model.sensor_dim[sid])
    if channel.component is None:
        if dim != 1:
            raise ModelError(
                f"{info.model_file}: sensor {name!r} has {dim} components; use scalar sensors or give channel "
                f"{channel.name!r} a component"
            )
        return int(model.sensor_adr[sid])
    if not 0 <= channel.component < dim:
        raise ModelError(
            f"{info.model_file}: channel {channel.name!r} reads component {channel.component} of sensor {name!r}, "
            f"which has components 0 to {dim - 1}"
        )
    return int(model.sensor_adr[sid]) + channel.component


def substeps(sample_time: float, timestep: float, where: str) -> int:
    """Physics steps per tick; the sample time must be a whole number of MuJoCo timesteps."""
    n = round(sample_time / timestep)
    if n < 1 or abs(n * timestep - sample_time) > 1e-9 * sample_time:
        raise ModelError(
            f"sample_time = {sample_time} s is not a whole multiple of the timestep {timestep} s of {where}; "
            f"choose a multiple such as {max(n, 1) * timestep:g} s"
        )
    return n
