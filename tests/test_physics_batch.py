"""The plants of a batch stepped as one MuJoCo batch: row for row, bit for bit, each ``Plant`` alone."""

from __future__ import annotations

import numpy as np
import pytest

import mjcf
from cosim.plant.physics import Plant
from cosim.plant.physics_batch import PhysicsBatch, PlantsEach, physics_of

_SAMPLING = {"masses": 0.01, "three_tank": 1.0}


def _plants(name: str, runs: int, seed: int) -> list[Plant]:
    """``runs`` plants of one kind, each from another initial state (the first at its keyframe)."""
    rng = np.random.default_rng(seed)
    plants = [Plant(mjcf.get(name), _SAMPLING[name]) for _ in range(runs)]
    for i, plant in enumerate(plants[1:], 1):
        x = plant.state()
        plant.set_state(x + rng.normal(0.0, 0.01 * i, x.shape))
    return plants


def _step_both(batch: PhysicsBatch, alone: list[Plant], ticks: int, seed: int) -> None:
    """Step the batch and the plants alone on the same inputs (every third tick a run sits out),
    holding their states and readings equal after every tick."""
    rng = np.random.default_rng(seed)
    runs, m, d = len(alone), len(alone[0].actuator_names), len(alone[0].disturbance_names)
    scale = 1.0 if alone[0].info.name == "masses" else 10.0
    for k in range(ticks):
        rows = np.array([r for r in range(runs) if (k + r) % 3 != 0])
        u, w = rng.normal(0.0, scale, (len(rows), m)), rng.normal(0.0, 0.01, (len(rows), d))
        assert batch.step(rows, u, w) == {}
        for i, r in enumerate(rows.tolist()):
            alone[r].step(u[i], w[i])
        assert np.array_equal(batch.state(), np.stack([p.state() for p in alone])), f"tick {k}"
        assert np.array_equal(batch.sensors(), np.stack([p.sensors() for p in alone])), f"tick {k}"


@pytest.mark.parametrize("name", sorted(_SAMPLING))
def test_a_physics_batch_steps_each_plant_as_it_steps_alone(name: str) -> None:
    batch = physics_of(_plants(name, 5, seed=1))
    assert isinstance(batch, PhysicsBatch)
    _step_both(batch, _plants(name, 5, seed=1), ticks=60 if name == "masses" else 25, seed=2)


def test_each_run_steps_on_its_own_model() -> None:
    """A campaign may give a run other plant parameters: its simulation uses its own model."""
    plants, alone = _plants("masses", 3, seed=3), _plants("masses", 3, seed=3)
    for each in (plants[2], alone[2]):
        each.model.jnt_stiffness[:] *= 1.7
    batch = physics_of(plants)
    assert isinstance(batch, PhysicsBatch)
    _step_both(batch, alone, ticks=40, seed=4)


def test_plants_the_batch_cannot_take_step_one_by_one() -> None:
    """The vessel's damping is a Python callback (MuJoCo's batch refuses those); plants of two
    samplings or kinds do not share a batch either."""
    vessel = [Plant(mjcf.get("vessel"), 0.1) for _ in range(2)]
    assert isinstance(physics_of(vessel), PlantsEach)
    masses = [Plant(mjcf.get("masses"), 0.01), Plant(mjcf.get("masses"), 0.02)]
    assert isinstance(physics_of(masses), PlantsEach)
    mixed = [Plant(mjcf.get("masses"), 1.0), Plant(mjcf.get("three_tank"), 1.0)]
    assert isinstance(physics_of(mixed), PlantsEach)
