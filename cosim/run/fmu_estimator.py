"""``cosim fmu --estimator NAME``: one estimator of a scenario, as its node runs it on the bus,
packaged as an FMI 3.0 or 2.0 co-simulation FMU (``cosim.run.fmu_estimator_slave`` is the slave
its Python runs).

The FMU is the estimator's node without the bus: its inputs are what the node's estimator gets
each tick (``cosim.run.node.EstimatorNode``: the readings as decoded from their frames, NaN for a
frame that did not arrive, and the commands, held), its outputs what it publishes (the estimate and
the diagnostics, by their DBC signal names), its parameters the fields of the kind's ``Params``.
The design is the run's: the scenario's plant linearized as ``cosim run`` does, the estimator
designed on it through the design cache, and what its node would be built with (``node_params``:
LMI gains, pole placements) frozen into the FMU, so that the FMU needs neither the plant nor the
design's solvers. Built-in kinds and users' plugins take the same path (``estimators.ESTIMATORS``);
a plugin's class travels in the FMU as its source file.

``bus_inputs`` reads, from a run's log, what a node read on the bus tick by tick: the FMU fed
these reproduces the node's logged estimates bit for bit (docs/fmi.md).
"""

from __future__ import annotations

import dataclasses
import inspect
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

import estimators
from cosim import __version__
from cosim.blas import one_thread
from cosim.errors import CosimError, ScenarioError
from cosim.kinds import KindError, is_file_reference
from estimators import Estimator, LinearModel, ParameterError

PLUGIN_FOLDER = "plugin"
#: A parameter's value unchanged when it reads the same to 16 digits: how FMI's XML carries it.
DIGITS = "{:.16g}"


def exported(loaded: Any, name: str) -> tuple[dict[str, Any], dict[str, Path]]:
    """What the FMU of estimator ``name`` of a loaded scenario holds: its ``content.json`` and the
    files beside it (a plugin's source, by its name in the resources)."""
    from cosim.run.plan import RunPlan
    from cosim.scenario import LoadedScenario

    s = loaded.scenario
    spec = next((e for e in s.estimators if e.name == name), None)
    if spec is None:
        known = ", ".join(e.name for e in s.estimators) or "none"
        raise ScenarioError(f"{loaded.source}: no estimator {name!r} (its estimators: {known})")
    alone = s.model_copy(update={"estimators": [spec], "controller": None, "clients": []})
    return content_of(RunPlan.build(LoadedScenario(alone, loaded.source, loaded.text)), name)


def content_of(plan: Any, name: str) -> tuple[dict[str, Any], dict[str, Path]]:
    """``exported``'s content of estimator ``name`` of a plan (``cosim.run.plan.RunPlan``), its
    outputs named as the plan's DBC names them, and the files beside it."""
    from cosim.bus.codec import estimated_state
    from cosim.run.fmu_export import fmi_units, model_identifier, variable

    s = plan.scenario
    spec = next(e for e in s.estimators if e.name == name)
    estimator = plan.estimators[name]
    model = estimator.model
    sensors, actuators, _ = s.channels()
    by_name = {c.name: c for c in [*sensors, *actuators]}
    outputs = [
        {**variable(channel), "name": signal, "state": estimated_state(signal)}
        for message in plan.codec.data_messages(name)
        for channel, signal in zip(message.channels, message.signals)
    ]
    readings = [variable(by_name[n]) for n in model.outputs]
    commands = [variable(by_name[n]) for n in model.inputs]
    given = {**spec.params, **estimator.node_params()}
    kind, files = _shipped(spec.kind, type(estimator))
    content = {
        "slave": "estimator",
        "model_identifier": model_identifier(f"{s.name}_{name}"),
        "description": f"cosim estimator {name} ({spec.kind}) of scenario {s.name}, sample time {s.sample_time:g} s",
        "cosim_version": __version__,
        "name": name,
        "kind": kind,
        "sample_time": s.sample_time,
        "duration": s.duration,
        "model": model.to_dict(),
        "params": given,
        "design": sorted(estimator.node_params()),
        "design_free": sorted(type(estimator).design_free),
        "parameters": list(parameters(type(estimator).check_params(given))),
        "readings": readings,
        "commands": commands,
        "outputs": outputs,
        "units": fmi_units([*readings, *commands, *outputs]),
    }
    return content, files


def _shipped(kind: str, cls: type[Estimator]) -> tuple[str, dict[str, Path]]:
    """The kind the FMU builds (a built-in's name, or a plugin's class in its shipped source file,
    relative to the resources) and the files to ship."""
    if estimators.ESTIMATORS.origin(kind).source == "built-in":
        return kind, {}
    source = Path(inspect.getsourcefile(cls) or "")
    shipped = f"{PLUGIN_FOLDER}/{source.name}"
    try:  # the file alone, as the FMU will import it
        estimators.ESTIMATORS[f"{source}:{cls.__qualname__}"]
    except KindError as error:
        raise CosimError(f"cosim fmu: estimator {kind!r} cannot travel as its file {source}: {error}") from None
    return f"{shipped}:{cls.__qualname__}", {shipped: source}


def parameters(params: Any) -> Iterator[dict[str, Any]]:
    """The fields of a ``Params`` value that FMI can hold, as the FMU's parameters: a number, a
    Boolean, a string, a list of numbers or a matrix (an FMI array); None, lists of names and
    ragged lists stay as exported."""
    for field in dataclasses.fields(params):
        value = getattr(params, field.name)
        found = _fmi_type(value)
        if found is not None:
            kind, shape = found
            described = f"Params.{field.name} = {json.dumps(value)} when exported"
            yield {
                "name": f"params.{field.name}",
                "field": field.name,
                "type": kind,
                "shape": shape,
                "value": list(map(list, value)) if len(shape) == 2 else list(value) if shape else value,
                "description": described if len(described) <= 200 else f"Params.{field.name}",
            }


def _fmi_type(value: Any) -> tuple[str, list[int]] | None:
    """The FMI type and array shape of a parameter value, or None where FMI has none for it."""
    if isinstance(value, bool):
        return "Boolean", []
    if isinstance(value, int):
        return "Int64", []
    if isinstance(value, float):
        return "Float64", []
    if isinstance(value, str):
        return "String", []
    if not isinstance(value, tuple) or not value:
        return None
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        return "Float64", [len(value)]
    rows = {len(row) if isinstance(row, tuple) else -1 for row in value}
    if len(rows) == 1 and min(rows) > 0 and all(isinstance(v, (int, float)) for row in value for v in row):
        return "Float64", [len(value), rows.pop()]
    return None


def build(content: dict[str, Any], resources: Path, values: dict[str, Any]) -> tuple[Estimator, list[tuple[str, str]]]:
    """The FMU's estimator, built as its node builds it (``estimators.create``) from the exported
    parameters with ``values`` (the FMU's parameters as set), and notes for the FMU's log: a
    redesign where a parameter the design depends on was changed, another cosim than the exporter."""
    notes = []
    if __version__ != content["cosim_version"]:
        notes.append(
            (
                "warning",
                f"exported by cosim {content['cosim_version']}, running on cosim {__version__}: the "
                "estimator's code may have changed since",
            )
        )
    exported = {p["field"]: p["value"] for p in content["parameters"]}
    changed = {f: values[f] for f in exported if _spelled(values[f]) != _spelled(exported[f])}
    params = {**content["params"], **changed}
    redesign = sorted(set(changed) - set(content["design"]) - set(content["design_free"]))
    if redesign:
        for name in content["design"]:
            if name not in changed:
                params.pop(name, None)
        notes.append(("ok", f"params.{', params.'.join(redesign)} changed: the design is redone at initialization"))
    kind = content["kind"]
    if is_file_reference(kind):  # a plugin's file, shipped in the resources
        kind = f"{resources / kind.partition(':')[0]}:{kind.partition(':')[2]}"
    model = LinearModel.from_dict(content["model"])
    try:
        with one_thread():  # as a node builds it
            return estimators.create(kind, model, params, content["sample_time"]), notes
    except ParameterError as error:
        raise CosimError(f"estimator {content['name']}: params.{error}") from None


def _spelled(value: Any) -> Any:
    """A parameter value as FMI's XML spells it (numbers to 16 digits)."""
    if isinstance(value, float):
        return DIGITS.format(value)
    if isinstance(value, (list, tuple)):
        return [_spelled(v) for v in value]
    return value


def export(loaded: Any, name: str, out: Path, fmi: int = 3) -> Path:
    """Write estimator ``name`` of a loaded scenario as an FMI ``fmi`` FMU to ``out``; returns ``out``."""
    from cosim.run.fmu_export import package

    content, files = exported(loaded, name)
    return package(content, out, fmi, files)


def bus_inputs(log: Path, name: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """What estimator node ``name`` read on the bus in a logged run, tick by tick: the ticks'
    times t_k and, by input name of its FMU, the readings (NaN where no frame arrived) and the
    commands (held, 0 before the first), as the node's ``TickAssembler`` put them together from
    the frames the log holds."""
    from cosim.bus.client import TickAssembler
    from cosim.bus.codec import CONTROLLER, Codec
    from cosim.log.metadata import LogMetadata, logged_dbc
    from cosim.log.reader import LogReader
    from cosim.run.replay import logged_ticks

    with LogReader(log) as reader:
        run = LogMetadata.read(reader.metadata()).run
        record = run.estimators.get(name) if run is not None else None
        if run is None or run.sample_time is None or record is None or record.model is None:
            known = ", ".join(run.estimators) if run is not None else "no cosim.run record"
            raise CosimError(f"{log}: no estimator {name!r} with its design model in this log ({known})")
        codec = Codec.from_dbc(logged_dbc(reader))
        model = LinearModel.from_dict(record.model)
        sample_time = run.sample_time
        upstream = {CONTROLLER: 0} if CONTROLLER in codec.node_ids else {}
        assembler = TickAssembler(codec, sample_time, upstream)
        ticks, rows = [], []
        u = np.zeros(model.m)
        for logged in logged_ticks(reader, codec):
            for frame in logged.frames:
                decoded = codec.decode(frame)
                for tick in assembler.push(decoded) if decoded is not None else []:
                    y = [tick.sensors.get(n, np.nan) for n in model.outputs]
                    u = np.array([tick.commands.get(n, u[i]) for i, n in enumerate(model.inputs)])
                    ticks.append(tick.tick)
                    rows.append([*y, *u])
    table = np.array(rows).reshape(len(rows), model.p + model.m)
    return np.array(ticks) * sample_time, dict(zip([*model.outputs, *model.inputs], table.T))


def write_bus_inputs(log: Path, name: str, out: Path) -> Path:
    """``bus_inputs`` as a CSV file (a ``time`` column, then one per input of the FMU, every value
    to 17 digits, ``nan`` for a missing reading): the input file of ``fmpy simulate --input-file``,
    a table for Simulink's or OMSimulator's signal sources."""
    t, inputs = bus_inputs(log, name)
    rows = [",".join(["time", *inputs])]
    rows += [
        ",".join(repr(float(v)) for v in (tk, *(column[i] for column in inputs.values()))) for i, tk in enumerate(t)
    ]
    out.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return out
