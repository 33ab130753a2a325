"""What the two slaves of ``cosim fmu`` share inside their FMUs: the FMI units of their variables
and the check of a step's size (the plant's ``cosim.run.fmu_slave``, an estimator's
``cosim.run.fmu_estimator_slave``).

Both FMUs advance a scenario tick by tick, so a ``doStep`` must span a whole number of sample
times τ; any other step is refused with ``fmi3Error`` and a message at [error] naming both sizes.
"""

from __future__ import annotations

from typing import Any
from xml.etree.ElementTree import Element

import numpy as np
from pythonfmu3 import Fmi3Slave, Fmi3Status
from pythonfmu3.fmi3slave import Fmi3StepResult
from pythonfmu3.unit import Unit

#: The ``doStep`` result that refuses a step.
REFUSED = Fmi3StepResult(status=Fmi3Status.error)


def register_units(slave: Fmi3Slave, units: dict[str, dict[str, Any]]) -> None:
    """Declare ``units`` (name → ``{"factor", "offset", "base"}``, ``cosim.run.fmu_units``'s) as
    the FMU's unit definitions; a unit without ``base`` is declared by its name alone."""
    slave.register_units(
        [
            Unit(name, factor=u["factor"], offset=u["offset"], **u["base"]) if "base" in u else NamedUnit(name)
            for name, u in units.items()
        ]
    )


class NamedUnit(Unit):
    """A unit declared by its name alone, without a BaseUnit (which would say it is dimensionless):
    what FMI allows for a unit whose SI form is not known."""

    def to_xml(self) -> Element:
        return Element("Unit", {"name": self.name})


def ticks_of(slave: Fmi3Slave, step_size: float, sample_time: float) -> int | None:
    """The number of sample times a step spans, or None (logged at [error]) if it is not a whole
    positive number of them."""
    ticks = round(step_size / sample_time)
    if ticks >= 1 and abs(ticks * sample_time - step_size) <= 1e-9 * max(step_size, 1.0):
        return ticks
    slave.log(
        f"the step size {step_size:g} s is not a whole multiple of the sample time {sample_time:g} s: refused",
        status=Fmi3Status.error,
    )
    return None


def about(v: dict[str, str]) -> dict[str, Any]:
    """A signal's description and unit as a variable's keywords (a unit only where it has one)."""
    return {"description": v["description"], **({"unit": v["unit"]} if v["unit"] else {})}


def element(values: np.ndarray, i: int) -> dict[str, Any]:
    """The getter and setter of one element of an array attribute."""

    def setter(value: float) -> None:
        values[i] = value

    return {"getter": lambda: float(values[i]), "setter": setter}
