"""An estimator inside the FMU that ``cosim fmu --estimator NAME`` exports, for FMI 2.0 and 3.0
alike (the adapters ``cosim.run.fmu_fmi2`` and ``cosim.run.fmu_fmi3`` drive it).

The FMU's ``resources/content.json`` (``cosim.run.fmu_estimator.exported``) holds the estimator's
kind, its parameters with the design computed at export (``node_params``: an LMI solution, a pole
placement), the linear model it is designed on, and its signals. Each tick it does what the
estimator's node does with a tick of the bus (``cosim.run.node.EstimatorNode``): xhat_k, diagnostics
= ``estimator.step(y_k, u_k)``. Its variables:

- inputs: the readings y_k as the node decodes them from the bus (NaN: no frame this tick), then
  the commands u_k (held, 0 before the first), both sampled at the start of a step;
- outputs: the estimate ``xhat_<state>`` and the diagnostics, by their signal names in the run's
  DBC: after the step from t_k, the answer to the inputs set at t_k (NaN before the first step);
  in a system, as the node's frames carry them (saturated to their signals' ranges, quantized on
  classic CAN), which is what the other nodes read and the log holds;
- parameters ``params.<name>``: the fields of the kind's ``Params`` that FMI can hold. Changing one
  that the design depends on redoes the design at initialization (on the exported linear model,
  with the design's own packages, e.g. cvxpy for an LMI); changing none runs the exported design.

A user's plugin estimator is shipped in the FMU's ``resources/plugin`` as the source file that
defines it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from cosim.bus.codec import Codec
from cosim.run.fmu_interface import Log, Slave, Variable, carried, signals


class EstimatorSlave(Slave):
    """An estimator of a scenario, as its node runs it."""

    def __init__(self, content: dict[str, Any], resources: Path, log: Log) -> None:
        super().__init__(content, resources, log)
        self.y = np.full(len(content["readings"]), np.nan)
        self.u = np.zeros(len(content["commands"]))
        self.out = np.full(len(content["outputs"]), np.nan)
        self.values: dict[str, Any] = {p["field"]: p["value"] for p in content["parameters"]}
        self.estimator: Any = None
        self.variables = [
            *(self._parameter(p) for p in content["parameters"]),
            *signals(content["readings"], self.y, "input"),
            *signals(content["commands"], self.u, "input"),
            *signals(content["outputs"], self.out, "output"),
        ]

    def _parameter(self, p: dict[str, Any]) -> Variable:
        """A field of ``Params`` as a fixed parameter (an array of Float64 for a list or a matrix)."""
        field, shape = p["field"], tuple(p["shape"])

        def get() -> Any:
            value = self.values[field]
            return np.ravel(value).tolist() if shape else value

        def set_(value: Any) -> None:
            self.values[field] = np.reshape(value, shape).tolist() if shape else value

        start = np.ravel(p["value"]).tolist() if shape else p["value"]
        return Variable(
            p["name"], p["type"], "parameter", "fixed", get, set_, start, "exact", p["description"], shape=shape
        )

    def initialize(self) -> None:
        from cosim.run.fmu_estimator import build

        self.estimator, notes = build(self.content, self.resources, self.values)
        for status, note in notes:
            self.log(note, status)
        states = self.estimator.model.states
        self._reads: list[Callable[[Any], float]] = [
            _state(states.index(v["state"])) if v["state"] is not None else _diagnostic(v["name"])
            for v in self.content["outputs"]
        ]
        self._names = [v["name"] for v in self.content["outputs"]]
        self._codec = Codec.from_dbc(self.system["dbc"]) if self.system is not None else None

    def tick(self, k: int) -> None:
        estimate = self.estimator.step(self.y.copy(), self.u.copy())
        values = [read(estimate) for read in self._reads]
        if self._codec is None:
            self.out[:] = values
            return
        sent = carried(self._codec, self.content["name"], dict(zip(self._names, values)), k, saturate=True)
        self.out[:] = [sent[name] for name in self._names]


def _state(index: int) -> Callable[[Any], float]:
    return lambda estimate: float(estimate.x[index])


def _diagnostic(name: str) -> Callable[[Any], float]:
    return lambda estimate: float(estimate.diagnostics[name])
