"""The simulated plant: a MuJoCo model (``physics``), a plant given by its matrices
(``statespace``) or an FMU (``fmu``, through FMPy), sampled at the scenario's tick and linearized at
its operating point."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from cosim.plant.fmu_model import is_fmu
from cosim.plant.physics import Plant
from cosim.plant.statespace import StateSpacePlant

if TYPE_CHECKING:
    from cosim.plant.fmu import FmuPlant


def build_plant(scenario: Any) -> Plant | StateSpacePlant | FmuPlant:
    """The plant a validated scenario names, at its keyframe (its operating point; the scenario's
    initial state is set by ``reset``). ModelError if its model is inconsistent."""
    s = scenario
    if is_fmu(s.plant.model):
        from cosim.plant.fmu import FmuPlant

        tolerance = None if s.plant.fmu is None else s.plant.fmu.tolerance
        return FmuPlant(
            s.fmu_model(), s.sample_time, s.duration, s.sensors, design=s.plant.state_space, tolerance=tolerance
        )
    if s.plant.state_space is not None:
        plant: Plant | StateSpacePlant = StateSpacePlant(s.plant.state_space, s.plant_info, s.sample_time, s.sensors)
    else:
        plant = Plant(s.plant_info, s.sample_time, s.sensors)
    return plant


__all__ = ["Plant", "StateSpacePlant", "build_plant"]
