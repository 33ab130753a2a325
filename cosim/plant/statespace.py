"""A plant given as state-space matrices instead of MJCF, for the papers' abstract examples.

``[plant] model = "state-space"`` with a ``[plant.state_space]`` table of A, B, C (and D) runs
x⁺ = A_d x + B_d u, y = C x + D u exactly: a continuous-time model (``time = "continuous"``) is
discretized at the sample time by the exact zero-order hold (one matrix exponential, Van Loan),
so the sampled trajectory equals the ODE's solution under piecewise-constant inputs; a
discrete-time model is taken as it is (its step is the sample time). The interface is the same as
``cosim.plant.physics.Plant``'s, so the runner and the estimators do not care which they get.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from cosim.bus.signals import Channel
from cosim.errors import ModelError
from estimators.design import zoh_discretize
from estimators.model import LinearModel
from mjcf import PlantInfo

NAME = "state-space"


def plant_info(spec: Any) -> PlantInfo:  # a StateSpaceSpec: the scenario's room is above the plant's
    """The PlantInfo of a ``[plant.state_space]`` table (a validated ``StateSpaceSpec``)."""

    def channels(names: Sequence[str], what: str) -> tuple[Channel, ...]:
        return tuple(
            Channel(n, spec.unit, f"{what} {n} of the state-space plant", -spec.bound, spec.bound, spec.resolution)
            for n in names
        )

    return PlantInfo(
        NAME,
        f"{spec.time}-time state-space plant with {len(spec.state_names)} states",
        "",
        channels(spec.state_names, "state"),
        channels(spec.output_names, "output"),
        channels(spec.input_names, "input"),
        disturbances=channels(spec.disturbance_names, "unknown input"),
    )


class StateSpacePlant:
    """Exactly integrated linear plant with the ``Plant`` interface."""

    def __init__(self, spec: Any, info: PlantInfo, sample_time: float, sensors: Sequence[str] | None = None) -> None:
        self.spec, self.info = spec, info
        self.sample_time = float(sample_time)
        self.A, self.B = np.array(spec.A, dtype=float), np.array(spec.B, dtype=float)
        self.C = np.array(spec.C, dtype=float)
        self.D = np.zeros((self.C.shape[0], self.B.shape[1])) if spec.D is None else np.array(spec.D, dtype=float)
        self.E = np.zeros((self.A.shape[0], 0)) if spec.E is None else np.array(spec.E, dtype=float)
        m = self.B.shape[1]
        if spec.time == "continuous":
            self.Ad, BEd = zoh_discretize(self.A, np.hstack([self.B, self.E]), self.sample_time)
            self.Bd, self.Ed = BEd[:, :m], BEd[:, m:]
        else:
            self.Ad, self.Bd, self.Ed = self.A, self.B, self.E
        self.state_names = tuple(spec.state_names)
        self.actuator_names = tuple(spec.input_names)
        self.disturbance_names = tuple(spec.disturbance_names)
        outputs = tuple(spec.output_names)
        self.sensor_names = tuple(sensors) if sensors is not None else outputs
        self._rows = [outputs.index(n) for n in self.sensor_names]
        self.reset()

    @property
    def nx(self) -> int:
        return self.A.shape[0]

    @property
    def time(self) -> float:
        return self._k * self.sample_time

    def reset(self, initial: dict[str, float] | None = None) -> None:
        self._k = 0
        self.x = np.zeros(self.nx)
        self.u = np.zeros(self.B.shape[1])
        for name, value in (initial or {}).items():
            self.x[self.state_names.index(name)] = value

    def state(self) -> np.ndarray:
        return self.x.copy()

    def set_state(self, x: np.ndarray) -> None:
        self.x = np.array(x, dtype=float)

    def sensors(self) -> np.ndarray:
        return (self.C @ self.x + self.D @ self.u)[self._rows]

    def step(self, ctrl: np.ndarray, disturbance: np.ndarray | None = None) -> None:
        self.u = np.array(ctrl, dtype=float)
        self.x = self.Ad @ self.x + self.Bd @ self.u
        if disturbance is not None and self.Ed.shape[1]:
            self.x = self.x + self.Ed @ np.asarray(disturbance, dtype=float)
        self._k += 1

    def linearize(
        self, x: np.ndarray | None = None, u: np.ndarray | None = None, *, continuous: bool = False, method: str = "zoh"
    ) -> LinearModel:
        """The model itself (it is linear): sampled at the sample time, or in continuous time."""
        if continuous and self.spec.time != "continuous":
            raise ModelError(
                'a continuous-time estimator needs a continuous-time plant: set plant.state_space.time = "continuous"'
            )
        A, B, E = (self.A, self.B, self.E) if continuous else (self.Ad, self.Bd, self.Ed)
        rows = self._rows
        return LinearModel(
            A,
            B,
            self.C[rows],
            self.D[rows],
            None if continuous else self.sample_time,
            self.state_names,
            self.actuator_names,
            self.sensor_names,
            E=E,
            disturbances=self.disturbance_names,
        )
