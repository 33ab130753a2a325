"""The Python inside an estimator's FMU that ``cosim fmu --estimator NAME`` exports (pythonfmu3
packages this file).

The FMU's ``resources/content.json`` (``cosim.run.fmu_estimator.exported``) holds the estimator's
kind, its parameters with the design computed at export (``node_params``: an LMI solution, a pole
placement), the linear model it is designed on, and its signals. Each tick it does what the
estimator's node does with a tick of the bus (``cosim.run.node.EstimatorNode``): xhat_k, diagnostics
= ``estimator.step(y_k, u_k)``. Its variables:

- inputs: the readings y_k as the node decodes them from the bus (NaN: no frame this tick), then
  the commands u_k (held, 0 before the first), both sampled at the start of a step;
- outputs: the estimate ``xhat_<state>`` and the diagnostics, by their signal names in the run's
  DBC: after the step from t_k, the answer to the inputs set at t_k (NaN before the first step);
- parameters ``params.<name>``: the fields of the kind's ``Params`` that FMI can hold. Changing one
  that the design depends on redoes the design at initialization (on the exported linear model,
  with the design's own packages, e.g. cvxpy for an LMI); changing none runs the exported design.

A step advances ``communicationStepSize`` / tau ticks (tau: the sample time; a whole number; the
inputs held over it); any other step size is refused (``fmi3Error``, logged at [error]). The host
needs a Python with cosim installed (e.g. FMPy in cosim's virtualenv); a user's plugin estimator
is shipped in the FMU's ``resources/plugin`` as the source file that defines it.

This file is ASCII: pythonfmu3 reads it in the locale's encoding (``cosim.run.fmu_export.package``).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from pythonfmu3 import (
    Boolean,
    DefaultExperiment,
    Dimension,
    Float64,
    Fmi3Causality,
    Fmi3Initial,
    Fmi3Slave,
    Fmi3Status,
    Fmi3Variability,
    Int64,
    String,
)
from pythonfmu3.fmi3slave import Fmi3StepResult

from cosim.run.fmu_interface import REFUSED, about, element, register_units, ticks_of

CONTENT = "content.json"
TYPES = {"Float64": Float64, "Int64": Int64, "Boolean": Boolean, "String": String}


class CosimEstimator(Fmi3Slave):
    """An estimator of a scenario as an FMI 3.0 co-simulation slave."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        content = json.loads((Path(self.resources) / CONTENT).read_text(encoding="utf-8"))
        self.content = content
        self.modelName = content["model_identifier"]
        self.description = content["description"]
        self.sample_time = float(content["sample_time"])
        self.default_experiment = DefaultExperiment(0.0, content["duration"], self.sample_time)
        self.time = 0.0
        self.y = np.full(len(content["readings"]), np.nan)
        self.u = np.zeros(len(content["commands"]))
        self.out = np.full(len(content["outputs"]), np.nan)
        self.values: dict[str, Any] = {p["field"]: p["value"] for p in content["parameters"]}
        self.estimator: Any = None
        register_units(self, content["units"])
        self.register_variable(
            Float64("time", causality=Fmi3Causality.independent, variability=Fmi3Variability.continuous)
        )
        for p in content["parameters"]:
            self._parameter(p)
        for group, values in (("readings", self.y), ("commands", self.u)):
            for i, v in enumerate(content[group]):
                variable = Float64(
                    v["name"],
                    causality=Fmi3Causality.input,
                    variability=Fmi3Variability.discrete,
                    start=values[i],
                    **about(v),
                    **element(values, i),
                )
                self.register_variable(variable, nested=False)
        for i, v in enumerate(content["outputs"]):
            variable = Float64(
                v["name"],
                causality=Fmi3Causality.output,
                variability=Fmi3Variability.discrete,
                initial=Fmi3Initial.calculated,
                **about(v),
                **element(self.out, i),
            )
            self.register_variable(variable, nested=False)

    def _parameter(self, p: dict[str, Any]) -> None:
        """A field of ``Params`` as a fixed parameter (an array of Float64 for a list or a matrix)."""
        field, shape = p["field"], p["shape"]

        def get() -> Any:
            value = self.values[field]
            return np.ravel(value).tolist() if shape else value

        def set_(value: Any) -> None:
            self.values[field] = np.reshape(value, shape).tolist() if shape else value

        variable = TYPES[p["type"]](
            p["name"],
            causality=Fmi3Causality.parameter,
            variability=Fmi3Variability.fixed,
            initial=Fmi3Initial.exact,
            start=p["value"] if not shape else np.ravel(p["value"]).tolist(),
            description=p["description"],
            getter=get,
            setter=set_,
            **({"dimensions": [Dimension(start=str(n)) for n in shape]} if shape else {}),
        )
        self.register_variable(variable, nested=False)

    def exit_initialization_mode(self) -> None:
        from cosim.run.fmu_estimator import build

        self.estimator, notes = build(self.content, Path(self.resources), self.values)
        for status, note in notes:
            self.log(note, status=Fmi3Status.warning if status == "warning" else Fmi3Status.ok)
        states = self.estimator.model.states
        self._reads: list[Callable[[Any], float]] = [
            _state(states.index(v["state"])) if v["state"] is not None else _diagnostic(v["name"])
            for v in self.content["outputs"]
        ]

    def do_step(self, current_time: float, step_size: float) -> Fmi3StepResult:
        ticks = ticks_of(self, step_size, self.sample_time)
        if ticks is None:
            return REFUSED
        for _ in range(ticks):
            estimate = self.estimator.step(self.y.copy(), self.u.copy())
            self.out[:] = [read(estimate) for read in self._reads]
        return Fmi3StepResult()


def _state(index: int) -> Callable[[Any], float]:
    return lambda estimate: float(estimate.x[index])


def _diagnostic(name: str) -> Callable[[Any], float]:
    return lambda estimate: float(estimate.diagnostics[name])
