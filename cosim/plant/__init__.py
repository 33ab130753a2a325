"""The simulated plant: a MuJoCo model (``physics``), a plant given by its matrices
(``statespace``) or an FMU (``fmu``, through FMPy), sampled at the scenario's tick and linearized at
its operating point.

MuJoCo (``physics``) is imported on first use of ``Plant``: an FMU's host process
(``cosim.plant.fmu_host``) never needs it."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from cosim.plant.fmu_model import is_fmu
from cosim.plant.statespace import StateSpacePlant

if TYPE_CHECKING:
    from cosim.plant.fmu_process import IsolatedFmuPlant
    from cosim.plant.physics import Plant


def __getattr__(name: str) -> Any:
    if name == "Plant":
        from cosim.plant.physics import Plant

        return Plant
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def build_plant(scenario: Any, interrupted: Any = None) -> Plant | StateSpacePlant | IsolatedFmuPlant:
    """The plant a validated scenario names, at its keyframe (its operating point; the scenario's
    initial state is set by ``reset``). ModelError if its model is inconsistent. ``interrupted``: for
    an FMU in a process of its own, what to call while it waits for the FMU (it raises to stop the run)."""
    s = scenario
    if is_fmu(s.plant.model):
        from cosim.plant.fmu_process import fmu_plant

        return fmu_plant(s, interrupted)
    if s.plant.state_space is not None:
        return StateSpacePlant(s.plant.state_space, s.plant_info, s.sample_time, s.sensors)
    from cosim.plant.physics import Plant

    return Plant(s.plant_info, s.sample_time, s.sensors)


__all__ = ["Plant", "StateSpacePlant", "build_plant"]
