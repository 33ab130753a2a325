"""The controller inside the FMU of a closed-loop system (``cosim fmu --system``), for FMI 2.0 and
3.0 alike (the adapters ``cosim.run.fmu_fmi2`` and ``cosim.run.fmu_fmi3`` drive it).

The FMU's ``resources/content.json`` (``cosim.run.fmu_system.controller_content``) holds the
controller's kind, parameters and design model, and its signals. Each tick it does what the
``controller`` node does with a tick of the bus (``cosim.run.node.ControllerNode``): u_k,
diagnostics = ``controller.step(y_k, t_k, report)``, the report being what its diagnosis node
published for tick k − 1 (nothing at tick 0). Its variables:

- inputs: the readings y_k as the node decodes them (NaN: no frame this tick), then
  ``<diagnosis>.<signal>``, every signal the diagnosis node publishes, as its frames carry them;
- outputs: the commands, named by their actuators, then the diagnostics of its ``CONTROL_STATUS``
  by their signal names, all as the controller's frames carry them (quantized on classic CAN): the
  commands the plant applies and the estimators read. A command outside its actuator's range is
  an error, as in a run (the controller must saturate what it asks for).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cosim.blas import one_thread
from cosim.bus.codec import CONTROLLER, Codec
from cosim.run.fmu_interface import Log, Slave, carried, signals


class ControllerSlave(Slave):
    """The scenario's controller, as its node runs it."""

    def __init__(self, content: dict[str, Any], resources: Path, log: Log) -> None:
        super().__init__(content, resources, log)
        self.y = np.full(len(content["readings"]), np.nan)
        self.report = np.full(len(content["report"]), np.nan)
        self.out = np.full(len(content["commands"]) + len(content["diagnostics"]), np.nan)
        self.controller: Any = None
        self.variables = [
            *signals(content["readings"], self.y, "input"),
            *signals(content["report"], self.report, "input", prefix=f"{content['diagnosis']}."),
            *signals([*content["commands"], *content["diagnostics"]], self.out, "output"),
        ]

    def initialize(self) -> None:
        from estimators import LinearModel
        from estimators import controller as controllers

        content = self.content
        model = LinearModel.from_dict(content["model"])
        with one_thread():  # as a node builds it
            self.controller = controllers.create(content["kind"], model, content["params"], self.sample_time)
        self._codec = Codec.from_dbc(self.system["dbc"]) if self.system is not None else None
        # the output of each signal: a command by its actuator's signal, a diagnostic by its own name
        self._signals = [v["signal"] for v in content["commands"]] + [v["name"] for v in content["diagnostics"]]

    def tick(self, k: int) -> None:
        names = [v["name"] for v in self.content["report"]]
        report = dict(zip(names, self.report.tolist())) if k >= 1 and names else {}  # the report of tick k - 1
        command = self.controller.step(self.y.copy(), k * self.sample_time, report)
        values = dict(zip(self._signals[: len(command.u)], map(float, command.u)))
        values |= {name: command.diagnostics[name] for name in self._signals[len(command.u) :]}
        if self._codec is not None:
            values = carried(self._codec, CONTROLLER, values, k)
        self.out[:] = [values[name] for name in self._signals]
