"""The Python of a cosim FMU for FMI 2.0 (pythonfmu packages this file): an adapter that declares
a slave's variables (``cosim.run.fmu_interface``) as pythonfmu's and drives the slave that the
FMU's ``resources/content.json`` names (the plant, an estimator, the controller).

What FMI 2.0 lacks is spelled its way: an array parameter is one scalar per element (``name[i]``,
``name[i,j]``, 1-based, the structured naming convention), an Int64 is an Integer (32 bits: the
exporter keeps larger values out), and the independent variable ``time`` is not declared (FMI 3.0
requires it; pythonfmu has no such causality). pythonfmu declares no units: this adapter adds the
unit definitions and each Real's ``unit`` to the model description. The host needs a Python with
cosim installed (its import path, e.g. FMPy in cosim's virtualenv).

This file is ASCII, as the FMI 3.0 one (``cosim.run.fmu_export.package``).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from typing import Any
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import (
    Boolean,
    DefaultExperiment,
    Fmi2Causality,
    Fmi2Initial,
    Fmi2Slave,
    Fmi2Variability,
    Integer,
    Real,
    String,
)
from pythonfmu.enums import Fmi2Status

from cosim.run.fmu_interface import Adapter, Variable, unit_element

TYPES = {"Float64": Real, "Int64": Integer, "Boolean": Boolean, "String": String}


class CosimSlave(Adapter, Fmi2Slave):
    """A cosim slave as an FMI 2.0 co-simulation slave."""

    status = {"ok": Fmi2Status.ok, "warning": Fmi2Status.warning, "error": Fmi2Status.error}
    experiment = DefaultExperiment

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.start()
        self.units: dict[str, str] = {}
        """Each scalar's unit, by its name."""
        for variable in self.slave.variables:
            for scalar in _scalars(variable):
                self.register_variable(scalar, nested=False)
                if variable.unit:
                    self.units[scalar.name] = variable.unit

    def to_xml(self, model_options: dict[str, str] | None = None) -> Element:
        """pythonfmu's model description with the unit definitions (after ``CoSimulation``, where
        FMI 2.0's schema has them), each Real's unit, and the initial unknowns (the outputs, which
        are calculated: FMI 2.0's ``ModelStructure`` lists them)."""
        root = super().to_xml(model_options or {})
        structure = root.find("ModelStructure")
        calculated = [i for i, v in enumerate(self.vars.values(), 1) if v.causality == Fmi2Causality.output]
        if structure is not None and calculated:
            unknowns = SubElement(structure, "InitialUnknowns")
            for index in calculated:
                SubElement(unknowns, "Unknown", {"index": str(index)})
        definitions = Element("UnitDefinitions")
        for name, unit in self.slave.content["units"].items():
            definitions.append(unit_element(name, unit))
        if len(definitions):
            at = list(root).index(root.find("CoSimulation")) + 1
            root.insert(at, definitions)
        for scalar in root.iter("ScalarVariable"):
            unit = self.units.get(scalar.get("name", ""))
            if unit is not None:
                scalar[0].set("unit", unit)
        return root

    def do_step(self, current_time: float, step_size: float) -> bool:
        if not self.slave.step(current_time, step_size):
            raise StepRefused("the step was refused (the message before says why)")
        return True


def _scalars(v: Variable) -> Iterator[Any]:
    """A slave's variable as pythonfmu's scalars: itself, or one per element of an array."""
    keywords: dict[str, Any] = {
        "causality": getattr(Fmi2Causality, v.causality),
        "variability": getattr(Fmi2Variability, v.variability),
        "description": v.description or None,
    }
    if v.initial is not None:
        keywords["initial"] = getattr(Fmi2Initial, v.initial)
    if not v.shape:
        yield TYPES[v.type](v.name, start=v.start, getter=v.getter, setter=v.setter, **keywords)
        return
    for flat, index in enumerate(itertools.product(*(range(1, n + 1) for n in v.shape))):
        name = f"{v.name}[{','.join(map(str, index))}]"
        getter, setter = _element_of(v, flat)
        yield TYPES[v.type](name, start=v.start[flat], getter=getter, setter=setter, **keywords)


def _element_of(v: Variable, flat: int) -> tuple[Callable[[], Any], Callable[[Any], None]]:
    """The getter and setter of element ``flat`` (row-major) of an array variable, whose own
    getter and setter take the whole array as a flat list."""

    def get() -> Any:
        return v.getter()[flat]

    def set_(value: Any) -> None:
        assert v.setter is not None
        values = list(v.getter())
        values[flat] = value
        v.setter(values)

    return get, set_


class StepRefused(Exception):
    """Raised out of ``do_step`` when the slave refused the step or a tick failed (its message is
    logged at [error] first). pythonfmu's library returns fmi2Fatal for any exception, and has no
    fmi2Error; a False would be fmi2Discard, a step done in part, which FMPy takes as the end of
    the simulation without a word."""
