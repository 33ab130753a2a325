"""The plant inside the FMU that ``cosim fmu`` exports, for FMI 2.0 and 3.0 alike (the adapters
``cosim.run.fmu_fmi2`` and ``cosim.run.fmu_fmi3`` drive it).

The FMU's ``resources/content.json`` holds the scenario (its resolved JSON,
``cosim.run.fmu_export.exported``); its plant, sensor and actuator faults, noise and disturbances
run here as in ``cosim run``, through the same ``PlantSource``, so the outputs are the sensor
stream a run logs (``measured`` of /truth/faults, NaN for a dropped frame) given the same commanded
inputs. Its variables:

- inputs: the actuators' commands (start: what they hold before a command), held over a step;
- outputs: the transmitted sensors' measured readings, then ``state.<name>``, the plant's states;
- parameter ``seed`` (fixed): the seed of the noise, the faults and the disturbance models.

In a system (``cosim fmu --system``) it is the runner's side of the bus: its outputs are the
readings as the sensor frames carry them (``PlantSource.frames``: quantized on classic CAN, NaN
for a frame not sent), and in an open loop it drives its actuators itself with the scenario's
inputs, as the runner does, and outputs those commands as their frames carry them (outputs named
by the actuators, in place of the inputs).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cosim.bus.codec import COMMAND, SENSOR
from cosim.run.fmu_interface import Log, Slave, Variable, signals


class PlantSlave(Slave):
    """A scenario's plant with its faults."""

    def __init__(self, content: dict[str, Any], resources: Path, log: Log) -> None:
        super().__init__(content, resources, log)
        self.seed = int(content["seed"])
        self.u = np.array(content["u_op"], dtype=float)
        self.y = np.full(len(content["sensors"]), np.nan)
        self.x = np.zeros(len(content["states"]))
        self.drives_itself = self.system is not None and not self.system["closed_loop"]
        """An open loop's system: the scenario's inputs drive the actuators, which are outputs."""

        def set_seed(value: int) -> None:
            self.seed = int(value)

        seed = Variable(
            "seed",
            "Int64",
            "parameter",
            "fixed",
            lambda: self.seed,
            set_seed,
            start=self.seed,
            initial="exact",
            description="seed of the noise, the faults and the disturbance models",
        )
        if self.drives_itself:
            actuators = signals(content["actuators"], self.u, "output")
        else:
            actuators = signals(content["actuators"], self.u, "input", variability="continuous")
        self.variables = [
            seed,
            *actuators,
            *signals(content["sensors"], self.y, "output"),
            *signals(content["states"], self.x, "output", prefix="state."),
        ]
        self.source: Any = None

    def initialize(self) -> None:
        from cosim.run.fmu_export import plant_source

        self.source = plant_source(self.content, self.resources, self.seed)
        if self.system is not None:
            self.source.closed_loop = self.system["closed_loop"]  # no command frames of its own in a closed loop
            self._where = {name: i for i, name in enumerate(self.source.scenario.sensors)}
            self._where_command = {name: i for i, name in enumerate(self.source.scenario.actuators)}
        self._sense(0)

    def tick(self, k: int) -> None:
        """Tick k's actuation (the actuator faults on the commands, the disturbances) and the
        plant's step, then tick k+1's sensing: the order of ``PlantSource``."""
        source = self.source
        u_eff, _, d = source.actuate(self.u.copy(), source.scenario.time(k))
        source.step(k, u_eff, d)
        self._sense(k + 1)

    def terminate(self) -> None:
        """Free the plant (a nested FMU's instance, in its host process where it has one)."""
        if self.source is not None:
            self.source.close()
            self.source = None

    def _sense(self, k: int) -> None:
        source = self.source
        self.x[:] = source.plant.state()
        if self.system is None:
            outcome = source.faults.sensors(source.plant.sensors(), source.scenario.time(k))
            self.y[:] = np.where(outcome.sent, outcome.measured, np.nan)
            return
        self.y[:] = np.nan  # a frame not sent
        for _, decoded in source.frames(k)[1:]:  # after SYNC: the sensor frames, then an open loop's commands
            channel, value = decoded.spec.channels[0].name, decoded.values[decoded.spec.signals[0]]
            if decoded.spec.role == SENSOR:
                self.y[self._where[channel]] = value
            elif decoded.spec.role == COMMAND:
                self.u[self._where_command[channel]] = value
