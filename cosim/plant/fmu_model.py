"""An FMU read as a plant: which of its variables are the sensors, actuators, disturbances, states
and parameters, as bus signals, and the one-line error of an FMU that cannot be one.

The mapping (docs/fmi.md):

- the FMU's outputs are the sensor candidates, its inputs the actuators, except the inputs the
  scenario names as disturbances (``[plant.fmu] disturbances``): unknown inputs, on no bus;
- the states are its continuous states (the variables its ``ModelStructure`` lists derivatives
  of, in that order), or the variables ``[plant.fmu] states`` names;
- a signal's bus name is the variable's name, with every run of characters a CAN signal name
  cannot hold (``.``, ``[``, ``(``…) turned into one ``_``; an element of an array variable (FMI
  3) is ``name_i`` (``name_i_j`` for a matrix, 1-based, in the FMU's row-major order);
- the unit is the variable's (or its declared type's), the range its declared ``min``/``max``
  (else ±``bound``), the classic-CAN resolution ``resolution`` (1 for integers and Booleans).

Numeric variables only (FMI 2 Real, Integer, Enumeration, Boolean; FMI 3 Float32/64, the integer
types, Enumeration, Boolean); strings, binaries and clocks are not signals. FMPy (the ``fmi``
extra) reads the model description.
"""

from __future__ import annotations

import difflib
import math
import re
import zipfile
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

from cosim.bus.signals import Channel
from cosim.errors import ModelError
from cosim.extras import require
from cosim.files import once_per_version
from mjcf import PlantInfo

#: The FMI versions cosim runs.
VERSIONS = ("2.0", "3.0")
INTERFACES = ("co-simulation", "model-exchange")
FLOATS = frozenset({"Real", "Float32", "Float64"})
NUMERIC = FLOATS | {
    "Integer",
    "Enumeration",
    "Boolean",
    *(f"{sign}Int{bits}" for sign in ("", "U") for bits in (8, 16, 32, 64)),
}


class FmuError(ModelError):
    """An FMU that cannot be the scenario's plant; the message starts with the scenario field."""


def is_fmu(model: str) -> bool:
    """Whether ``[plant] model`` names an FMU file (rather than a registered plant)."""
    return model.lower().endswith(".fmu")


def fmpy() -> Any:
    """FMPy, or the one-line MissingExtra naming the ``fmi`` extra."""
    return require("fmpy", "an FMU plant", "fmi")


@dataclass(frozen=True)
class Element:
    """One scalar of an FMU variable: its bus signal and where it sits in the FMU."""

    channel: Channel
    variable: Any
    """FMPy's ``ModelVariable``."""
    index: int = 0
    """Its position among the variable's values (0 for a scalar)."""

    @property
    def name(self) -> str:
        return self.channel.name

    @property
    def discrete(self) -> bool:
        return self.variable.type not in FLOATS


@dataclass(frozen=True)
class FmuModel:
    """An FMU's variables as a plant's signals (``read`` builds it, checked)."""

    path: Path
    description: Any
    """FMPy's ``ModelDescription``."""
    interface: str
    states: tuple[Element, ...]
    sensors: tuple[Element, ...]
    actuators: tuple[Element, ...]
    disturbances: tuple[Element, ...]
    continuous_states: tuple[Element, ...]
    """The continuous states in the FMU's order (those of model exchange), each of which the
    ``derivatives`` (same order) are the time derivatives."""
    derivatives: tuple[Element, ...]
    parameters: dict[str, Any] = field(default_factory=dict)
    """The scenario's parameter values by variable name (checked to be parameters)."""
    settings: dict[str, Any] = field(default_factory=dict)
    """The ``[plant.fmu]`` settings it was read with (FmuSpec's fields)."""
    directional: bool = False
    """Whether its model-exchange interface provides directional derivatives (FMI 2
    ``providesDirectionalDerivative``, FMI 3 ``providesDirectionalDerivatives``)."""

    @property
    def version(self) -> int:
        return int(self.description.fmiVersion[0])

    @property
    def has_model_exchange(self) -> bool:
        return self.description.modelExchange is not None

    def info(self) -> PlantInfo:
        """The plant's signals, in the shape every plant declares them."""
        md = self.description
        about = f": {md.description}" if md.description else ""
        return PlantInfo(
            self.path.name,
            f"FMI {md.fmiVersion} {self.interface} FMU {md.modelName!r}{about}",
            str(self.path),
            tuple(e.channel for e in self.states),
            tuple(e.channel for e in self.sensors),
            tuple(e.channel for e in self.actuators),
            disturbances=tuple(e.channel for e in self.disturbances),
        )


def start_value(element: Element) -> float:
    """The start value of one scalar of a variable (its element of an array's start), as a float;
    without one, 0 (an enumeration's first item)."""
    v = element.variable
    if v.start is None:
        items = v.declaredType.items if v.type == "Enumeration" and v.declaredType is not None else None
        return float(items[0].value) if items else 0.0
    values = str(v.start).split() if v.shape else [str(v.start)]
    text = values[element.index] if element.index < len(values) else values[-1]
    if v.type == "Boolean":
        return 1.0 if text.strip().lower() in ("true", "1") else 0.0
    return float(text)


#: What ``read`` found, by (path, modification time, size, table): ``Scenario.plant_info`` is asked often.
_READ: dict[tuple[Any, ...], FmuModel] = {}


def read(path: str | Path, spec: Any) -> FmuModel:
    """The FMU at ``path`` (absolute) as a plant under the scenario's ``[plant.fmu]`` table (a
    validated ``FmuSpec``); FmuError in one line if it cannot be one."""
    path = Path(path)
    missing = FmuError(f"plant.model: no FMU at {path} (a path relative to the scenario file)")
    return once_per_version(_READ, path, spec, missing, _read)


def read_fresh(path: str | Path, spec: Any) -> FmuModel:
    """``read`` without its cache, ``spec`` any object with FmuSpec's attributes (an FMU's host
    process reads the FMU again from the settings it is sent)."""
    return _read(Path(path), spec)


def _read(path: Path, spec: Any) -> FmuModel:
    md, root = _description(path, spec.validate)
    interface = _interface(path, md, spec.interface)
    variables = {v.name: v for v in md.modelVariables}
    numeric = [v for v in md.modelVariables if v.type in NUMERIC]

    def elements(chosen: Iterable[Any]) -> tuple[Element, ...]:
        return tuple(e for v in chosen for e in _elements(v, spec, md))

    inputs = [v for v in numeric if v.causality == "input"]
    _known(path, "plant.fmu.disturbances", spec.disturbances, [v.name for v in inputs], "input")
    disturbances = [variables[name] for name in spec.disturbances]
    continuous = [d.variable.derivative for d in md.derivatives]
    if spec.states is not None:
        _known(path, "plant.fmu.states", spec.states, [v.name for v in numeric if v.type in FLOATS], "Float variable")
        state_variables = [variables[name] for name in spec.states]
    else:
        state_variables = continuous
    settable = [v.name for v in md.modelVariables if v.causality in ("parameter", "structuralParameter")]
    _known(path, "plant.fmu.parameters", list(spec.parameters), settable, "parameter")
    structural = [name for name in spec.parameters if variables[name].causality == "structuralParameter"]
    if structural:
        raise FmuError(
            f"plant.fmu.parameters: {path.name}: {', '.join(structural)} is a structural parameter (it sizes "
            "arrays); cosim runs an FMU with its structural parameters at their start values"
        )
    model = FmuModel(
        path,
        md,
        interface,
        elements(state_variables),
        elements(v for v in numeric if v.causality == "output"),
        elements(v for v in inputs if v.name not in spec.disturbances),
        elements(disturbances),
        elements(continuous),
        elements(d.variable for d in md.derivatives),
        dict(spec.parameters),
        spec.model_dump() if hasattr(spec, "model_dump") else dict(vars(spec)),
        _provides_directional_derivatives(md, root),
    )
    _distinct(path, model)
    return model


def _description(path: Path, validate: bool = True) -> tuple[Any, ElementTree.Element]:
    """FMPy's model description and the XML's root, after the checks that need only the archive:
    an FMU of a supported FMI version with a binary for this machine; ``validate``: its
    modelDescription.xml checked against the FMI schema (and FMPy's rules)."""
    lib = fmpy()
    try:
        with zipfile.ZipFile(path) as archive:
            root = ElementTree.fromstring(archive.read("modelDescription.xml"))
    except (zipfile.BadZipFile, KeyError, OSError, ElementTree.ParseError) as error:
        raise FmuError(f"plant.model: {path} is not an FMU (a zip with a modelDescription.xml): {error}") from None
    version = root.get("fmiVersion", "?")
    if not version.startswith(VERSIONS):
        raise FmuError(
            f"plant.model: {path.name} is an FMI {version} FMU; cosim runs FMI {' and '.join(VERSIONS)} FMUs"
        )
    platforms = lib.supported_platforms(str(path))
    if lib.platform not in platforms:
        built = ", ".join(p for p in platforms if p != "c-code") or "no platform"
        sources = " (it also has its C sources: compile them for this machine)" if "c-code" in platforms else ""
        raise FmuError(
            f"plant.model: {path.name} has binaries for {built}, not for this machine ({lib.platform}){sources}"
        )
    try:
        return lib.read_model_description(str(path), validate=validate), root
    except Exception as error:  # noqa: BLE001 (FMPy raises plain Exceptions for an invalid description)
        problems = [line.strip("- ").strip() for line in str(error).splitlines()[1:] if line.strip()]
        first = problems[0] if problems else str(error)
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        way_out = " to run it anyway: [plant.fmu] validate = false (or cosim run --no-validate)" if validate else ""
        raise FmuError(
            f"plant.model: {path.name}: its modelDescription.xml is not valid FMI {version}: {first}{more};{way_out}"
        ) from None


def _provides_directional_derivatives(md: Any, root: ElementTree.Element) -> bool:
    """The model-exchange capability flag (FMPy reads FMI 2's spelling only, not FMI 3's)."""
    if md.modelExchange is None:
        return False
    if md.fmiVersion.startswith("2"):
        return bool(md.modelExchange.providesDirectionalDerivative)
    element = root.find("ModelExchange")
    return element is not None and element.get("providesDirectionalDerivatives") == "true"


def _interface(path: Path, md: Any, wanted: str | None) -> str:
    have = [name for name, part in zip(INTERFACES, (md.coSimulation, md.modelExchange)) if part is not None]
    if not have:
        raise FmuError(f"plant.model: {path.name} has neither a co-simulation nor a model-exchange interface")
    if wanted is not None and wanted not in have:
        raise FmuError(f"plant.fmu.interface: {path.name} has no {wanted} interface (it has: {', '.join(have)})")
    return wanted or have[0]


def _known(path: Path, field_name: str, names: Iterable[str], known: list[str], what: str) -> None:
    for name in names:
        if name not in known:
            close = difflib.get_close_matches(name, known, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            listed = f"; its {what}s: {', '.join(known)}" if known else f"; it has no {what}s"
            raise FmuError(f"{field_name}: {path.name} has no {what} {name!r}{hint}{listed}")


def bus_name(name: str) -> str:
    """A CAN signal name for an FMU variable name: runs of other characters become one ``_``."""
    cleaned = re.sub(r"[^A-Za-z0-9_]+", "_", name).strip("_") or "v"
    return cleaned if cleaned[0].isalpha() else f"v_{cleaned}"


def _elements(variable: Any, spec: Any, md: Any) -> list[Element]:
    """A variable's scalars as bus signals."""
    shape = tuple(variable.shape or ())
    size = 1
    for extent in shape:
        size *= extent
    declared = variable.declaredType
    unit = variable.unit or (declared.unit if declared is not None else None) or ""
    discrete = variable.type not in FLOATS
    low, high = bus_range(variable, declared, spec.bound)
    # A wide range gets a coarser classic-CAN resolution (the relative one of ±bound at `resolution`), so
    # that it fits a frame: a signal in Pa or N never needs more bits than one of the default range.
    resolution = 1.0 if discrete else spec.resolution * max(1.0, max(abs(low), abs(high)) / spec.bound)
    description = variable.description or f"{variable.causality} {variable.name} of {md.modelName}"
    found = []
    for index in range(size):
        suffix = "" if not shape else "_" + "_".join(str(i + 1) for i in _unravel(index, shape))
        channel = Channel(bus_name(variable.name) + suffix, unit, description, low, high, resolution)
        found.append(Element(channel, variable, index))
    return found


def _unravel(index: int, shape: tuple[int, ...]) -> list[int]:
    """Row-major (FMI's order) indices of the ``index``-th element of an array of ``shape``."""
    indices = []
    for extent in reversed(shape):
        index, i = divmod(index, extent)
        indices.append(i)
    return indices[::-1]


def bus_range(variable: Any, declared: Any, bound: float) -> tuple[float, float]:
    """A variable's range on the bus: its declared ``min``/``max`` (its own, else its type's); a
    side it does not declare ±bound·scale, scale its ``nominal`` (else its start value's magnitude,
    at least 1); 0 to 1 for a Boolean."""
    if variable.type == "Boolean":
        return 0.0, 1.0
    nominal = _attribute(variable, declared, "nominal")
    if nominal:
        scale = abs(nominal)
    else:
        starts = (
            [abs(float(x)) for x in str(variable.start).split() if _number(x)] if variable.start is not None else []
        )
        scale = max([1.0, *starts])
    span = bound * scale
    low, high = _attribute(variable, declared, "min"), _attribute(variable, declared, "max")
    if low is not None and high is not None:
        return (low, high) if low < high else (-span, span)
    if low is not None:
        return low, span if span > low else low + 2.0 * span
    if high is not None:
        return -span if -span < high else high - 2.0 * span, high
    return -span, span


def _attribute(variable: Any, declared: Any, key: str) -> float | None:
    """A numeric attribute of the variable, else of its declared type (None: neither gives one)."""
    for source in (variable, declared):
        value = getattr(source, key, None) if source is not None else None
        if value is not None and _number(str(value)):
            return float(value)
    return None


def _number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


def _distinct(path: Path, model: FmuModel) -> None:
    """Two variables whose bus names coincide cannot both be signals."""
    for group in (model.sensors, model.actuators + model.disturbances, model.states):
        seen: dict[str, str] = {}
        for element in group:
            other = seen.setdefault(element.name, element.variable.name)
            if other != element.variable.name:
                raise FmuError(
                    f"plant.model: {path.name}: variables {other!r} and {element.variable.name!r} both become the "
                    f"bus signal {element.name!r}"
                )
