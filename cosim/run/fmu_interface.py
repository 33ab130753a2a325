"""What the slaves of ``cosim fmu`` share inside their FMUs, whatever the FMI version: the variables
they declare (``Variable``), the behaviour an FMI adapter drives (``Slave``), and the ticks a step
spans.

Each slave's behaviour is written once, FMI-neutrally: the plant (``cosim.run.fmu_slave``), an
estimator (``cosim.run.fmu_estimator_slave``), the controller (``cosim.run.fmu_controller_slave``).
The FMI 3.0 adapter (``cosim.run.fmu_fmi3``, over pythonfmu3) and the FMI 2.0 one
(``cosim.run.fmu_fmi2``, over pythonfmu) are the Python files the FMUs carry: they read
``resources/content.json``, build the behaviour it names, declare its variables in their library's
classes and call ``initialize``, ``step`` and ``terminate``.

A slave advances a scenario tick by tick. On its own (``cosim fmu``), a ``doStep`` spans a whole
number of sample times τ and runs that many ticks. In a system (``cosim fmu --system``) every FMU
takes exactly the system's step and does tick k's work in the step that holds t_k + phase·τ
(``ticks``); any other step is refused with an error status and one message at [error].
"""

from __future__ import annotations

import importlib
import json
import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.etree.ElementTree import Element, SubElement

import numpy as np

from cosim.bus.codec import Codec, saturated
from cosim.errors import CosimError

#: The file in an FMU's resources that its slave is built from.
CONTENT = "content.json"
#: The behaviours, by the name ``content.json`` gives as ``slave``.
SLAVES = {
    "plant": "cosim.run.fmu_slave:PlantSlave",
    "estimator": "cosim.run.fmu_estimator_slave:EstimatorSlave",
    "controller": "cosim.run.fmu_controller_slave:ControllerSlave",
}
#: How far from a whole number of ticks a time may be (FMI's times are floats, libcosim's whole ns).
TICK_TOLERANCE = 1e-6

#: A message for the FMU's log, and its status: "ok", "warning" or "error".
Log = Callable[[str, str], None]


@dataclass
class Variable:
    """One variable of a slave, as both FMI versions declare it: ``type`` is FMI 3's name
    (``Float64``, ``Int64``, ``Boolean``, ``String``; FMI 2.0's Real, Integer, Boolean, String),
    ``shape`` an array's (FMI 2.0 has none: one scalar per element, ``name[i]``, ``name[i,j]``)."""

    name: str
    type: str
    causality: str  # parameter, input, output
    variability: str  # fixed, discrete, continuous
    getter: Callable[[], Any]
    setter: Callable[[Any], None] | None = None
    start: Any = None
    initial: str | None = None  # exact, calculated; None where FMI forbids it (inputs)
    description: str = ""
    unit: str = ""
    shape: tuple[int, ...] = ()


def element(values: np.ndarray, i: int) -> dict[str, Any]:
    """The getter and setter of one element of an array attribute."""

    def setter(value: float) -> None:
        values[i] = value

    return {"getter": lambda: float(values[i]), "setter": setter}


def about(v: dict[str, str]) -> dict[str, Any]:
    """A signal's description and unit (``cosim.run.fmu_export.variable``) as a variable's fields."""
    return {"description": v["description"], "unit": v["unit"]}


def signals(
    group: list[dict[str, str]], values: np.ndarray, causality: str, prefix: str = "", variability: str = "discrete"
) -> list[Variable]:
    """Float64 inputs or outputs, one per signal of ``group``, each an element of ``values``: an
    input starts at its element's value, an output is calculated."""
    made = []
    for i, v in enumerate(group):
        kind = {"start": float(values[i])} if causality == "input" else {"initial": "calculated"}
        name = prefix + v["name"]
        made.append(Variable(name, "Float64", causality, variability, **element(values, i), **kind, **about(v)))
    return made


def carried(codec: Codec, sender: str, values: dict[str, float], k: int, saturate: bool = False) -> dict[str, float]:
    """The values of node ``sender``'s messages for tick k (by signal name) as its frames carry them:
    what the other nodes decode from what ``Client.publish`` sends (with ``saturate``, each value at
    the bound of its signal's range it crossed, as an estimator's node sends it). A value the frame
    cannot carry (outside its range, NaN) is a CodecError naming the signal, as in a run."""
    found: dict[str, float] = {}
    for spec in codec.data_messages(sender):
        payload = [values[signal] for signal in spec.signals]
        _, decoded = codec.encode_decoded(spec.name, k, saturated(payload, spec.channels) if saturate else payload)
        found.update(decoded.values)
    return found


def unit_element(name: str, unit: dict[str, Any]) -> Element:
    """The FMI unit definition (the same element in FMI 2.0 and 3.0) of ``cosim.run.fmu_export.fmi_unit``'s
    form of a unit; one without ``base`` is declared by its name alone."""
    found = Element("Unit", {"name": name})
    if "base" in unit:
        attributes = {key: str(value) for key, value in unit["base"].items() if value != 0}
        if unit["factor"] != 1.0:
            attributes["factor"] = str(unit["factor"])
        if unit["offset"] != 0.0:
            attributes["offset"] = str(unit["offset"])
        SubElement(found, "BaseUnit", attributes)
    return found


class Slave(ABC):
    """A slave's behaviour: its variables, and what it does at initialization, each tick and the end.

    ``content`` is its ``content.json``; ``system`` there (absent on its own) holds the system's
    ``step`` (every ``doStep`` must be that long), its ``phase`` and the run's DBC."""

    def __init__(self, content: dict[str, Any], resources: Path, log: Log) -> None:
        self.content = content
        self.resources = resources
        self.log = log
        self.sample_time = float(content["sample_time"])
        self.system: dict[str, Any] | None = content.get("system")
        self.phase = float(self.system["phase"]) if self.system is not None else 0.0
        self.variables: list[Variable] = []

    @property
    def step_size(self) -> float:
        """The step of its default experiment: the system's, else the sample time."""
        return float(self.system["step"]) if self.system is not None else self.sample_time

    def initialize(self) -> None:  # noqa: B027 (a slave with nothing to build keeps it)
        """Leave initialization mode: the parameters are set."""

    @abstractmethod
    def tick(self, k: int) -> None:
        """Do tick k's work with the inputs as they are."""

    def terminate(self) -> None:  # noqa: B027 (a slave that holds nothing keeps it)
        """Free what the slave holds."""

    def step(self, t: float, h: float) -> bool:
        """Advance from t by h: every tick whose work falls in [t, t + h), in order; False (logged
        at [error]) for a step the slave refuses or a tick that failed (a value the bus cannot carry)."""
        ticks = self.ticks(t, h)
        if ticks is None:
            return False
        try:
            for k in ticks:
                self.tick(k)
        except CosimError as error:
            self.log(str(error), "error")
            return False
        return True

    def ticks(self, t: float, h: float) -> range | None:
        """The ticks k with t ≤ (k + phase)·τ < t + h, or None (logged at [error]) where h is not a
        step the slave takes: a whole positive number of sample times on its own, exactly the
        system's step in a system."""
        tau = self.sample_time
        if self.system is not None:
            step = float(self.system["step"])
            if abs(h - step) > 1e-9 * max(step, 1.0):
                self.log(
                    f"the step size {h:g} s is not the system's step {step:g} s ({self.system['why']}): refused",
                    "error",
                )
                return None
        else:
            n = round(h / tau)
            if n < 1 or abs(n * tau - h) > 1e-9 * max(h, 1.0):
                self.log(
                    f"the step size {h:g} s is not a whole multiple of the sample time {tau:g} s: refused", "error"
                )
                return None
        first = math.ceil(t / tau - self.phase - TICK_TOLERANCE)
        return range(first, math.ceil((t + h) / tau - self.phase - TICK_TOLERANCE))


def read_content(resources: Path) -> dict[str, Any]:
    """An FMU's ``content.json``."""
    content: dict[str, Any] = json.loads((resources / CONTENT).read_text(encoding="utf-8"))
    return content


def load(resources: Path, log: Log) -> Slave:
    """The slave ``content.json`` in ``resources`` describes."""
    content = read_content(resources)
    module, _, name = SLAVES[content["slave"]].partition(":")
    slave: Slave = getattr(importlib.import_module(module), name)(content, resources, log)
    return slave


class Adapter:
    """What the FMI 2.0 and 3.0 adapters (``fmu_fmi2``, ``fmu_fmi3``) share, mixed in before their
    library's slave class: the slave their resources name, the model's name, description and default
    experiment, its messages in the log at their FMI status, initialization and termination."""

    status: dict[str, Any]
    """The FMI version's status of each of ``Log``'s: ok, warning, error."""
    experiment: Callable[..., Any]
    """The library's DefaultExperiment."""
    resources: str
    log: Callable[..., None]
    modelName: str  # noqa: N815 (the libraries' attribute)
    description: str
    default_experiment: Any

    def start(self) -> dict[str, Any]:
        """Load the slave of the FMU's resources and describe the model by it; returns its content."""
        self.slave = load(Path(self.resources), self._log)
        content = self.slave.content
        self.modelName = content["model_identifier"]
        self.description = content["description"]
        self.default_experiment = self.experiment(0.0, content["duration"], self.slave.step_size)
        return content

    def _log(self, message: str, status: str) -> None:
        self.log(message, status=self.status[status])

    def exit_initialization_mode(self) -> None:
        self.slave.initialize()

    def terminate(self) -> None:
        self.slave.terminate()
