"""The Python of a cosim FMU for FMI 3.0 (pythonfmu3 packages this file): an adapter that declares
a slave's variables (``cosim.run.fmu_interface``) as pythonfmu3's and drives the slave that the
FMU's ``resources/content.json`` names (the plant, an estimator, the controller).

FMI 3.0 has arrays: a parameter of a list or a matrix is one variable with its dimensions. The
host needs a Python with cosim installed (its import path, e.g. FMPy in cosim's virtualenv).

This file is ASCII: pythonfmu3 reads it in the locale's encoding (``cosim.run.fmu_export.package``).
"""

from __future__ import annotations

from typing import Any
from xml.etree.ElementTree import Element

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
from pythonfmu3.unit import Unit

from cosim.run.fmu_interface import Adapter, Variable, unit_element

TYPES = {"Float64": Float64, "Int64": Int64, "Boolean": Boolean, "String": String}


class CosimSlave(Adapter, Fmi3Slave):
    """A cosim slave as an FMI 3.0 co-simulation slave."""

    status = {"ok": Fmi3Status.ok, "warning": Fmi3Status.warning, "error": Fmi3Status.error}
    experiment = DefaultExperiment

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        content = self.start()
        self.time = 0.0
        self.register_units([DefinedUnit(name, unit) for name, unit in content["units"].items()])
        self.register_variable(
            Float64("time", causality=Fmi3Causality.independent, variability=Fmi3Variability.continuous)
        )
        for variable in self.slave.variables:
            self.register_variable(_declared(variable), nested=False)

    def do_step(self, current_time: float, step_size: float) -> Fmi3StepResult:
        if not self.slave.step(current_time, step_size):
            return Fmi3StepResult(status=Fmi3Status.error)
        self.time = current_time + step_size
        return Fmi3StepResult()


class DefinedUnit(Unit):
    """A unit definition as ``cosim.run.fmu_interface.unit_element`` writes it (by its name alone
    where its SI form is not known: a BaseUnit would say it is dimensionless)."""

    def __init__(self, name: str, definition: dict[str, Any]) -> None:
        super().__init__(name)
        self.definition = definition

    def to_xml(self) -> Element:
        return unit_element(self.name, self.definition)


def _declared(v: Variable) -> Any:
    """A slave's variable as pythonfmu3's (an array with its dimensions)."""
    keywords: dict[str, Any] = {
        "causality": getattr(Fmi3Causality, v.causality),
        "variability": getattr(Fmi3Variability, v.variability),
        "description": v.description,
        "getter": v.getter,
        "setter": v.setter,
    }
    if v.initial is not None:
        keywords["initial"] = getattr(Fmi3Initial, v.initial)
    if v.start is not None:
        keywords["start"] = v.start
    if v.unit:
        keywords["unit"] = v.unit
    if v.shape:
        keywords["dimensions"] = [Dimension(start=str(n)) for n in v.shape]
    return TYPES[v.type](v.name, **keywords)
