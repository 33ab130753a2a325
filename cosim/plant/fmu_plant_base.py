"""What both FMU plants share (``FmuPlant``, the FMU in the runner's process; ``IsolatedFmuPlant``,
the FMU in a host process): what they know of the FMU before it runs (its ``PlantInfo``, its
elements' names, the inputs' start values, the design model) and the clock of their ticks."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from cosim.plant.fmu_model import FmuModel, start_value
from cosim.plant.statespace import StateSpacePlant


class FmuPlantBase:
    """An FMU plant's declared side: ``sample_time`` s per tick, ``duration`` the run's stop time,
    ``sensors`` the sensors read (all the FMU's by default), ``design`` an optional
    ``[plant.state_space]`` design model (a ``StateSpaceSpec``)."""

    def __init__(
        self, model: FmuModel, sample_time: float, duration: float, sensors: Sequence[str] | None, design: Any
    ) -> None:
        self.model = model
        self.info = model.info()
        self.sample_time, self.duration = float(sample_time), float(duration)
        self.state_names = tuple(e.name for e in model.states)
        self.actuator_names = tuple(e.name for e in model.actuators)
        self.disturbance_names = tuple(e.name for e in model.disturbances)
        self.sensor_names = tuple(sensors) if sensors is not None else tuple(e.name for e in model.sensors)
        self.start_inputs = np.array([start_value(e) for e in model.actuators + model.disturbances], dtype=float)
        """The inputs' start values (actuators, then disturbance inputs): what an undriven input holds."""
        self.design = None if design is None else StateSpacePlant(design, self.info, sample_time, self.sensor_names)
        self.warnings: list[str] = []
        """What the linearization found doubtful (directional derivatives against differences)."""
        self.operating_point = ""
        """Where the last linearization was taken, where that is not the start point as it stands: the
        equilibrium reached from it, or an affine model about it ("" at an equilibrium)."""
        self._k = 0  # the tick the plant is at

    @property
    def nx(self) -> int:
        return len(self.state_names)

    @property
    def time(self) -> float:
        return self._k * self.sample_time
