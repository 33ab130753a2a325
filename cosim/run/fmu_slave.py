"""The Python inside the plant's FMU that ``cosim fmu`` exports (pythonfmu3 packages this file).

The FMU's ``resources/content.json`` holds the scenario (its resolved JSON,
``cosim.run.fmu_export.exported``); its plant, sensor and actuator faults, noise and disturbances
run here as in ``cosim run``, through the same ``PlantSource``, so the outputs are the sensor
stream a run logs (``measured`` of /truth/faults, NaN for a dropped frame) given the same commanded
inputs. Its variables:

- inputs: the actuators' commands (start: the operating point's), held over a step;
- outputs: the transmitted sensors' measured readings, then ``state.<name>``, the plant's states;
- parameter ``seed`` (fixed): the seed of the noise, the faults and the disturbance models.

A step advances ``communicationStepSize`` / tau ticks (a whole number) of the scenario's sample time
tau; any other step size is refused (``fmi3Error``, logged at [error]). The host needs a Python
with cosim installed (its import path, e.g. FMPy in cosim's virtualenv).

This file is ASCII: pythonfmu3 reads it in the locale's encoding (``cosim.run.fmu_export.package``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from pythonfmu3 import DefaultExperiment, Float64, Fmi3Causality, Fmi3Initial, Fmi3Slave, Fmi3Variability, Int64
from pythonfmu3.fmi3slave import Fmi3StepResult

from cosim.run.fmu_interface import REFUSED, about, element, register_units, ticks_of

CONTENT = "content.json"


class CosimPlant(Fmi3Slave):
    """A scenario's plant with its faults as an FMI 3.0 co-simulation slave."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        exported = json.loads((Path(self.resources) / CONTENT).read_text(encoding="utf-8"))
        self.exported = exported
        self.modelName = exported["model_identifier"]
        self.description = exported["description"]
        self.sample_time = float(exported["sample_time"])
        self.default_experiment = DefaultExperiment(0.0, exported["duration"], self.sample_time)
        self.seed = int(exported["seed"])
        self.u = np.array(exported["u_op"], dtype=float)
        self.y = np.full(len(exported["sensors"]), np.nan)
        self.x = np.zeros(len(exported["states"]))
        self.time = 0.0
        register_units(self, exported["units"])
        self.register_variable(
            Float64("time", causality=Fmi3Causality.independent, variability=Fmi3Variability.continuous)
        )
        self.register_variable(
            Int64(
                "seed",
                causality=Fmi3Causality.parameter,
                variability=Fmi3Variability.fixed,
                initial=Fmi3Initial.exact,
                description="seed of the noise, the faults and the disturbance models",
            )
        )
        for i, v in enumerate(exported["actuators"]):
            self.register_variable(
                Float64(v["name"], causality=Fmi3Causality.input, start=self.u[i], **about(v), **element(self.u, i)),
                nested=False,
            )
        for prefix, group, values in (("", "sensors", self.y), ("state.", "states", self.x)):
            for i, v in enumerate(exported[group]):
                self.register_variable(
                    Float64(
                        prefix + v["name"],
                        causality=Fmi3Causality.output,
                        variability=Fmi3Variability.discrete,
                        initial=Fmi3Initial.calculated,
                        **about(v),
                        **element(values, i),
                    ),
                    nested=False,
                )
        self.source: Any = None

    def exit_initialization_mode(self) -> None:
        from cosim.run.fmu_export import plant_source

        self.source = plant_source(self.exported, Path(self.resources), self.seed)
        self._k = 0
        self._sense()

    def do_step(self, current_time: float, step_size: float) -> Fmi3StepResult:
        ticks = ticks_of(self, step_size, self.sample_time)
        if ticks is None:
            return REFUSED
        self._k = round(current_time / self.sample_time)
        for _ in range(ticks):
            self._advance()
        return Fmi3StepResult()

    def terminate(self) -> None:
        """Free the plant (a nested FMU's instance, in its host process where it has one)."""
        if self.source is not None:
            self.source.close()
            self.source = None

    def _advance(self) -> None:
        """Tick k's actuation (the actuator faults on the held commands, the disturbances) and the
        plant's step, then tick k+1's sensing: the order of ``PlantSource``."""
        source, s = self.source, self.source.scenario
        t = s.time(self._k)
        u_eff, _ = source.faults.actuators(self.u.copy(), t)
        d = np.array([w(t) for w in source.disturbances]) + sum(
            (b(t) for b in source.environments), np.zeros(len(source.disturbances))
        )
        source.plant.step(u_eff, d)
        self._k += 1
        self._sense()

    def _sense(self) -> None:
        source = self.source
        outcome = source.faults.sensors(source.plant.sensors(), source.scenario.time(self._k))
        self.y[:] = np.where(outcome.sent, outcome.measured, np.nan)
        self.x[:] = source.plant.state()
