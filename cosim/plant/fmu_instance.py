"""An FMU instance's calls, as the plant (``cosim.plant.fmu``) and its linearization
(``cosim.plant.fmu_linear``) make them through FMPy: its variables read and written as one float
array (``Access``), and instantiating, initializing, stepping and freeing it, with every call
watched (``cosim.plant.fmu_calls``).
"""

from __future__ import annotations

import ctypes
import locale
from collections.abc import Sequence
from typing import Any

import numpy as np

from cosim.errors import ModelError
from cosim.plant.fmu_calls import CallWatch, FmuCallError, fmi2_callbacks
from cosim.plant.fmu_model import Element, FmuModel


class Access:
    """Reads and writes a fixed list of an FMU's scalars (``Element``) as one float array: one FMI
    call per variable type (all its variables' value references at once)."""

    def __init__(self, elements: Sequence[Element], version: int) -> None:
        self.elements = tuple(elements)
        self.version = version
        variables: dict[int, Any] = {}
        for e in self.elements:
            variables.setdefault(id(e.variable), e.variable)
        self.variables = list(variables.values())
        # The variables by FMI type; each type's values are one slice of the flat buffer, each
        # variable's values start at offset[variable] in it.
        by_type: dict[str, list[Any]] = {}
        for v in self.variables:
            by_type.setdefault(_type_name(v, version), []).append(v)
        self._groups: list[tuple[str, list[int], int, int, list[Any]]] = []
        self._offset, position = {}, 0
        for type_name, group in by_type.items():
            start = position
            for v in group:
                self._offset[id(v)] = position
                position += _size(v)
            self._groups.append((type_name, [v.valueReference for v in group], start, position, group))
        self._size = position
        self._take = np.array([self._offset[id(e.variable)] + e.index for e in self.elements], dtype=int)
        # An enumeration variable takes only its items' values.
        self._items = {
            id(v): frozenset(int(item.value) for item in v.declaredType.items)
            for v in self.variables
            if v.type == "Enumeration" and v.declaredType is not None and v.declaredType.items
        }

    def get(self, fmu: Any) -> np.ndarray:
        buffer = np.zeros(self._size)
        for type_name, references, start, end, _ in self._groups:
            count = (end - start,) if self.version == 3 else ()
            buffer[start:end] = getattr(fmu, "get" + type_name)(references, *count)
        return buffer[self._take]

    def set(self, fmu: Any, values: np.ndarray) -> None:
        buffer = np.zeros(self._size)
        buffer[self._take] = values
        for type_name, references, _, _, group in self._groups:
            typed = []
            for v in group:
                chunk = [_typed(v, value) for value in buffer[self._offset[id(v)] : self._offset[id(v)] + _size(v)]]
                if id(v) in self._items:
                    self._check_items(v, chunk)
                typed += chunk
            getattr(fmu, "set" + type_name)(references, typed)

    def _check_items(self, v: Any, values: list[Any]) -> None:
        items = self._items[id(v)]
        for value in values:
            if value not in items:
                listed = ", ".join(f"{item.value} ({item.name})" for item in v.declaredType.items)
                raise ModelError(
                    f"input {v.name} (enumeration {v.declaredType.name}) would be set to {value}, which is none of its "
                    f"items: {listed}; check its input signal and actuator faults"
                )


def _size(variable: Any) -> int:
    return int(np.prod(variable.shape)) if variable.shape else 1


def _type_name(variable: Any, version: int) -> str:
    if variable.type == "Enumeration":
        return "Integer" if version == 2 else "Int64"
    return str(variable.type)


def _typed(variable: Any, value: float) -> Any:
    if variable.type == "Boolean":
        return bool(value != 0)
    return float(value) if variable.type in ("Real", "Float32", "Float64") else int(round(value))


def set_continuous_states(fmu: Any, x: np.ndarray) -> None:
    """Set a model-exchange instance's continuous states."""
    values = np.ascontiguousarray(x, dtype=float)
    fmu.setContinuousStates(values.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), len(values))


def start_values(model: FmuModel, initial: dict[str, float] | None) -> dict[str, Any]:
    """The start values to set, by FMU variable name: the scenario's parameters and the named
    states' initial values (an element of an array variable changes that element of its start)."""
    values: dict[str, Any] = dict(model.parameters)
    by_name = {e.name: e for e in model.states}
    for name, value in (initial or {}).items():
        element = by_name[name]
        v = element.variable
        if v.initial not in ("exact", "approx") or v.causality == "independent":
            raise ModelError(
                f"{model.path.name}: state {name} ({v.name}) has no start value to set (its initial is "
                f"{v.initial or 'calculated'}); set the parameter that initializes it in [plant.fmu] parameters"
            )
        if v.shape:
            current = values.get(v.name, [float(s) for s in str(v.start).split()])
            current = list(current)
            current[element.index] = value
            values[v.name] = current
        else:
            values[v.name] = value
    return values


def instantiate(model: FmuModel, unzipped: str, interface: str, watch: CallWatch) -> Any:
    """An FMU instance of the given interface (as ``fmpy.simulation.instantiate_fmu`` makes it), its
    calls and log messages watched by ``watch`` (FMI 2: the process's callbacks, ``fmi2_callbacks``)."""
    from fmpy.simulation import instantiate_fmu

    md = model.description
    cs = interface == "co-simulation"
    watch.instantiating()
    # Some exporters' runtimes (Dymola's) call setlocale(LC_ALL, "C") when instantiated; in this
    # process that would make Python's default text encoding ASCII, so the locale is put back.
    kept = locale.setlocale(locale.LC_ALL)
    try:
        if model.version == 3:
            fmu = instantiate_fmu(unzipped, md, "CoSimulation" if cs else "ModelExchange", logger=watch.logger())
        else:
            from fmpy.fmi2 import FMU2Model, FMU2Slave

            part = md.coSimulation if cs else md.modelExchange
            fmu = (FMU2Slave if cs else FMU2Model)(
                guid=md.guid, unzipDirectory=unzipped, modelIdentifier=part.modelIdentifier, instanceName=None
            )
            fmu.instantiate(callbacks=fmi2_callbacks())
    except FmuCallError:
        raise
    except Exception as error:  # noqa: BLE001 (FMPy raises plain Exceptions when a library does not load)
        raise ModelError(
            f"{model.path.name}: cannot instantiate its {interface} interface: {error}; {watch.last_words()}"
        ) from None
    finally:
        locale.setlocale(locale.LC_ALL, kept)
    return watch.watch(fmu)


def release(fmu: Any, watch: CallWatch) -> None:
    """Terminate and free an instance, as far as its state allows (nothing after a Fatal status,
    only freeing after an error)."""
    if watch.fatal:
        return
    if watch.failure is None:
        try:
            fmu.terminate()
        except FmuCallError:
            pass
    try:
        fmu.freeInstance()
    except FmuCallError:
        pass


def initialize(
    model: FmuModel, fmu: Any, interface: str, start: dict[str, Any], tolerance: float | None, stop_time: float
) -> float | None:
    """Initialize an instance at t = 0 as ``fmpy.simulate_fmu`` does (start values before and in
    initialization mode, the experiment's tolerance and stop time); a model-exchange instance is
    left in continuous-time mode after the initial event iteration. Returns the next time event."""
    from fmpy.simulation import apply_start_values, settable_in_initialization_mode, settable_in_instantiated

    md = model.description
    me = interface == "model-exchange"
    remaining = apply_start_values(fmu, md, start, settable=settable_in_instantiated)
    if model.version == 2:
        fmu.setupExperiment(tolerance=None if me else tolerance, startTime=0.0, stopTime=stop_time)
        fmu.enterInitializationMode()
    else:
        fmu.enterInitializationMode(tolerance=None if me else tolerance, startTime=0.0, stopTime=stop_time)
    remaining = apply_start_values(fmu, md, remaining, settable=settable_in_initialization_mode)
    if remaining:
        raise ModelError(f"{model.path.name}: cannot set {', '.join(remaining)} (not settable before initialization)")
    fmu.exitInitializationMode()
    if not me:
        return None
    terminate, event_time = update_discrete_states(model, fmu)
    if terminate:
        raise ModelError(f"{model.path.name}: the FMU ended the simulation during its initialization")
    fmu.enterContinuousTimeMode()
    return event_time


def update_discrete_states(model: FmuModel, fmu: Any) -> tuple[bool, float | None]:
    """The event iteration of model exchange: (terminate, the next time event or None)."""
    update = fmu.newDiscreteStates if model.version == 2 else fmu.updateDiscreteStates
    needed, terminate, defined, event_time = True, False, False, 0.0
    while needed and not terminate:
        needed, terminate, _, _, defined, event_time = update()
    return terminate, float(event_time) if defined else None


def do_step(model: FmuModel, fmu: Any, t: float, h: float) -> None:
    """One co-simulation step; an FMU that stops early or ends the simulation is a ModelError."""
    if model.version == 2:
        fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        return
    _, terminate, early_return, last = fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
    if terminate or early_return:
        when = last if early_return else t + h
        raise ModelError(f"{model.path.name}: the FMU ended the simulation at t = {when:g} s")
