"""The plants of a batch's K runs stepped as one: MuJoCo's ``mujoco.batch.Batch``, a leading run axis.

Each run of a batch (``cosim.campaign.batch``) has its own ``Plant``: its own compiled model (a
campaign may give each run other plant parameters), its initial state and inputs. ``PhysicsBatch``
steps their simulations in one call of ``mujoco.batch.Batch`` (persistent, one MjData per
simulation, each on its run's own model through ``set_models``), which MuJoCo documents as
bit-identical to a loop of ``mj_step`` over them, and reads their states and sensors as (K, ·)
arrays: row for row what each ``Plant``'s ``step``, ``state`` and ``sensors`` give
(``tests/test_physics_batch.py``). The saving is the per-run Python around each ``mj_step``, not the
integration itself, which stays each simulation's own.

``physics_of`` falls back to ``PlantsEach``, each plant stepped by itself, where the batch cannot
take the plants: a plant whose forces come from a Python callback (the vessel's body-frame damping,
``mjcb_passive``: MuJoCo's batch calls refuse Python callbacks), a plant that is not a MuJoCo
``Plant`` (a state-space or a plugin's), or plants whose samplings differ.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import mujoco
import mujoco.batch
import numpy as np

from cosim.plant.mujoco_model import CALLBACKS
from cosim.plant.physics import Plant
from estimators.batched import mv


class Physics(Protocol):
    """The K plants of a batch: their states and true readings as (K, ·) arrays, and a step of some."""

    def state(self) -> np.ndarray: ...

    def sensors(self) -> np.ndarray: ...

    def step(self, rows: np.ndarray, ctrl: np.ndarray, disturbance: np.ndarray) -> dict[int, str]:
        """Advance the plants of ``rows`` over one tick with ``ctrl`` (rows, m) and ``disturbance``
        (rows, d); the rows whose simulation failed, with MuJoCo's message (their state is not to be
        trusted: the run goes alone)."""
        ...


class PlantsEach:
    """Any plants, each stepped by its own ``step`` (what the runs do alone)."""

    def __init__(self, plants: Sequence[Any]) -> None:
        self.plants = list(plants)

    def state(self) -> np.ndarray:
        return np.stack([plant.state() for plant in self.plants])

    def sensors(self) -> np.ndarray:
        return np.stack([plant.sensors() for plant in self.plants])

    def step(self, rows: np.ndarray, ctrl: np.ndarray, disturbance: np.ndarray) -> dict[int, str]:
        for r, u, d in zip(rows.tolist(), ctrl, disturbance):
            self.plants[r].step(u, d)
        return {}


class PhysicsBatch:
    """MuJoCo plants of one layout and sampling (``batchable``) stepped in one ``Batch`` call."""

    def __init__(self, plants: Sequence[Plant]) -> None:
        first = plants[0]
        self.substeps = first.substeps
        self.known, self.unknown = first.actuator_index, first.disturbance_index
        self.tendons = first.tendons
        self.sensor_index, self.sensor_zero = first.sensor_index, first.sensor_zero
        self.batch = mujoco.batch.Batch(first.model, nsim=len(plants), nthread=1, persistent=True)
        self.batch.set_models([plant.model for plant in plants])  # FatalError: a model of another layout
        for row, plant in zip(self.batch.state, plants):  # each run's state as its Plant was reset to it
            mujoco.mj_getState(plant.model, plant.data, row, mujoco.mjtState.mjSTATE_INTEGRATION)
        with CALLBACKS:
            self.batch.forward()
        self.ctrl = self.batch.bind("ctrl")
        self.qpos, self.qvel, self.act = self.batch.bind("qpos"), self.batch.bind("qvel"), self.batch.bind("act")
        self.sensordata = self.batch.bind("sensordata")

    def state(self) -> np.ndarray:
        """Each plant's ``state()``: [qpos, qvel, act], or its state tendons' lengths T qpos."""
        if self.tendons is not None:
            return mv(self.tendons, np.ascontiguousarray(self.qpos))
        return np.concatenate([self.qpos, self.qvel, self.act], axis=1)

    def sensors(self) -> np.ndarray:
        return self.sensordata[:, self.sensor_index] - self.sensor_zero

    def step(self, rows: np.ndarray, ctrl: np.ndarray, disturbance: np.ndarray) -> dict[int, str]:
        """``Plant.step`` of each row: the inputs held over the tick, ``mj_step`` ``substeps`` times,
        then ``mj_forward`` for the sensors at the new state (``mjSTAGE_ACC``)."""
        if not len(rows):
            return {}
        self.ctrl[rows[:, None], self.known] = ctrl
        self.ctrl[rows[:, None], self.unknown] = disturbance
        try:
            with CALLBACKS:  # no other thread's plant may install its Python callback meanwhile
                self.batch.step(rows, nstep=self.substeps, stage=mujoco.mjtStage.mjSTAGE_ACC)
        except mujoco.batch.SimulationError:
            failed = rows[self.batch.status[rows] != 0]
            return {int(r): self.batch.error(int(r)) or "MuJoCo failed" for r in failed}
        return {}


def batchable(plants: Sequence[Any]) -> bool:
    """Whether ``PhysicsBatch`` may step ``plants``: MuJoCo plants without a Python callback, of one
    sampling and sensor selection (``set_models`` checks that their models have one layout)."""
    if not plants or not all(type(p) is Plant and p.passive_forces is None for p in plants):
        return False
    first = plants[0]
    return all(
        p.substeps == first.substeps
        and np.array_equal(p.sensor_index, first.sensor_index)
        and np.array_equal(p.sensor_zero, first.sensor_zero)
        and np.array_equal(p.actuator_index, first.actuator_index)
        and np.array_equal(p.disturbance_index, first.disturbance_index)
        and _same_tendons(p.tendons, first.tendons)
        for p in plants[1:]
    )


def physics_of(plants: Sequence[Any]) -> Physics:
    """The plants of a batch as one ``Physics``: in one MuJoCo call where they allow it."""
    if batchable(plants):
        try:
            return PhysicsBatch(plants)
        except mujoco.FatalError:  # models of other layouts (another plant's parameters may add bodies)
            pass
    return PlantsEach(plants)


def _same_tendons(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))
