"""The simulated plant: a MuJoCo model (``physics``) or a plant given by its matrices (``statespace``),
sampled at the scenario's tick and linearized at its operating point."""

from __future__ import annotations

from typing import Any

from cosim.plant.physics import Plant
from cosim.plant.statespace import StateSpacePlant


def build_plant(scenario: Any) -> Plant | StateSpacePlant:
    """The plant a validated scenario names, at its keyframe (its operating point; the scenario's
    initial state is set by ``reset``). ModelError if its model is inconsistent."""
    s = scenario
    if s.plant.state_space is not None:
        plant: Plant | StateSpacePlant = StateSpacePlant(s.plant.state_space, s.plant_info, s.sample_time, s.sensors)
    else:
        plant = Plant(s.plant_info, s.sample_time, s.sensors)
    return plant


__all__ = ["Plant", "StateSpacePlant", "build_plant"]
