"""A MuJoCo plant sampled at the scenario's tick (its linearization: ``cosim.plant.physics_linear``).

The dynamics come from ``mj_step`` only. The state is MuJoCo's [qpos, qvel, act], or, for a plant
that declares ``state_tendons`` (the three-tank system: levels), the lengths of those fixed tendons;
the plant module (``mjcf/<plant>.py``) names its components, the sensors and the actuators.

Forces a plant's MJCF cannot express (``PlantInfo.passive_forces``: the vessel's body-frame
damping) reach MuJoCo through its one process-wide passive-force callback, ``mjcb_passive``. A
plant installs it only for the duration of its own MuJoCo calls (``Plant.physics``,
``PassiveForces``) and puts the previous callback back: after any step, reset or linearization
``mjcb_passive`` is what it was before, and a plant without such forces never touches it. A process
that ran one plant runs the next as a fresh process would (docs/process-state.md).
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np

from cosim.errors import ModelError
from cosim.plant.mujoco_model import (
    CALLBACKS,
    actuator_ids,
    load_model,
    passive_forces,
    quasi_static_velocities,
    sensor_address,
    state_tendon_matrix,
    substeps,
)
from cosim.plant.physics_linear import linearize
from estimators.model import LinearModel
from mjcf import PlantInfo


class Plant:
    """One MuJoCo simulation of a plant, advanced ``sample_time`` seconds per tick.

    ``sensors`` selects and orders the transmitted sensors (default: all the plant declares).
    """

    def __init__(self, info: PlantInfo, sample_time: float, sensors: Sequence[str] | None = None) -> None:
        self.info = info
        self.model = load_model(info)
        self.data = mujoco.MjData(self.model)
        self.passive_forces = passive_forces(self.model, info)
        self.sample_time = float(sample_time)
        self.substeps = substeps(self.sample_time, self.model.opt.timestep, info.model_file)
        self.sensor_names = tuple(sensors) if sensors is not None else tuple(s.name for s in info.sensors)
        self.sensor_index = np.array([sensor_address(self.model, info, name) for name in self.sensor_names], dtype=int)
        self.sensor_zero = np.array([info.sensor(name).zero for name in self.sensor_names])
        self.actuator_names = tuple(a.name for a in info.actuators)
        self.disturbance_names = tuple(d.name for d in info.disturbances)
        self.actuator_index = actuator_ids(self.model, self.actuator_names)
        """Where the actuators' commands go in MuJoCo's ``ctrl`` (as ``actuator_names``)."""
        self.disturbance_index = actuator_ids(self.model, self.disturbance_names)
        """Where the disturbance inputs go in ``ctrl`` (as ``disturbance_names``)."""
        self.state_names = tuple(s.name for s in info.states)
        self.operating_point = ""
        """What the last linearization found where its point is no equilibrium ("" where it is)."""
        # State tendons: lengths = T @ qpos (fixed tendons); T⁺ places qpos for requested lengths.
        self.tendons = state_tendon_matrix(self.model, info)
        """T: the state tendons' lengths are T @ qpos (None: the state is [qpos, qvel, act])."""
        self.tendons_pinv = None if self.tendons is None else np.linalg.pinv(self.tendons)
        self.reset()

    @property
    def nx(self) -> int:
        if self.tendons is not None:
            return self.tendons.shape[0]
        return self.model.nq + self.model.nv + self.model.na

    @property
    def time(self) -> float:
        return float(self.data.time)

    def physics(self) -> contextlib.AbstractContextManager[Any]:
        """The context in which MuJoCo calls on this plant's model (any MjData of it) compute all of
        its physics: ``with plant.physics(): mujoco.mj_forward(plant.model, d)``. The plant's own
        methods use it; outside the block nothing of the plant is installed in MuJoCo. It holds
        ``CALLBACKS``: plants in other threads wait."""
        return CALLBACKS if self.passive_forces is None else self.passive_forces

    def forward(self, data: mujoco.MjData | None = None) -> None:
        """``mj_forward`` on the plant's data (or another MjData of its model), with all its physics."""
        with self.physics():
            mujoco.mj_forward(self.model, self.data if data is None else data)

    def reset(self, initial: dict[str, float] | None = None, keyframe: str | None = None) -> None:
        """Back to the plant's keyframe (or the one named; none: qpos0), then override the named state
        components."""
        keyframe = keyframe or self.info.keyframe
        if not keyframe:  # a model of the user's without keyframes: its qpos0
            mujoco.mj_resetData(self.model, self.data)
        elif (key := mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_KEY, keyframe)) < 0:
            raise ModelError(f'{self.info.model_file}: no keyframe named {keyframe!r}; add <key name="{keyframe}"/>')
        else:
            mujoco.mj_resetDataKeyframe(self.model, self.data, key)
        if initial or self.tendons is not None:  # tendon states: flows quasi-steady for the keyframe's ctrl
            x = self.state()
            for name, value in (initial or {}).items():
                x[self.state_names.index(name)] = value
            self.set_state(x)
        self.forward()

    def state(self) -> np.ndarray:
        """[qpos, qvel, act], or the state tendons' lengths; a copy."""
        if self.tendons is not None:
            return self.tendons @ self.data.qpos
        return np.concatenate([self.data.qpos, self.data.qvel, self.data.act])

    def set_state(self, x: np.ndarray) -> None:
        """Set [qpos, qvel, act]; or, with state tendons, give them the lengths ``x`` by the
        least-norm change of qpos (T⁺ (x − T qpos)) and put the velocities at their quasi-steady
        values for the current ctrl (``quasi_static_velocities``)."""
        m = self.model
        if self.tendons is not None:
            assert self.tendons_pinv is not None
            self.data.qpos[:] += self.tendons_pinv @ (np.asarray(x, dtype=float) - self.tendons @ self.data.qpos)
            with self.physics():
                self.data.qvel[:] = quasi_static_velocities(m, self.data)
            self.forward()
            return
        self.data.qpos[:] = x[: m.nq]
        self.data.qvel[:] = x[m.nq : m.nq + m.nv]
        self.data.act[:] = x[m.nq + m.nv :]
        self.forward()

    def sensors(self) -> np.ndarray:
        """The selected sensors' true readings at the current state, a copy."""
        return self.data.sensordata[self.sensor_index] - self.sensor_zero

    def step(self, ctrl: np.ndarray, disturbance: np.ndarray | None = None) -> None:
        """Hold the known inputs ``ctrl`` and the unknown inputs ``disturbance`` (default 0) for
        one sample time (zero-order hold) and advance the physics."""
        self.data.ctrl[self.actuator_index] = ctrl
        self.data.ctrl[self.disturbance_index] = 0.0 if disturbance is None else disturbance
        with CALLBACKS if self.passive_forces is None else self.passive_forces:
            mujoco.mj_step(self.model, self.data, nstep=self.substeps)
            # mj_step leaves sensordata at the state before its last integration; refresh it.
            mujoco.mj_forward(self.model, self.data)

    def linearize(
        self, x: np.ndarray | None = None, u: np.ndarray | None = None, *, continuous: bool = False, method: str = "zoh"
    ) -> LinearModel:
        """The plant linearized at (x, u) (default: the current state and ctrl), in discrete time at
        the sample time or in continuous time; see ``cosim.plant.physics_linear``."""
        return linearize(self, x, u, dt=None if continuous else self.sample_time, method=method)
