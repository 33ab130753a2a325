"""Loading a scenario: TOML text or a built-in name in, one validated ``Scenario`` or one error out.

Structure and types are checked first (pydantic, ``cosim.scenario.spec``); once those are right,
``check`` looks at the scenario as a whole: names the plant does not have, vector lengths,
estimator and controller parameters, fault labels, the bus signals. Every problem is reported in
one ScenarioError, each naming its field (``faults[0].value``) and the fix.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

import scenarios
from cosim.bus.codec import CONTROLLER, PLANT
from cosim.errors import CodecError, ScenarioError
from cosim.plant import statespace
from cosim.scenario.faults import OnBus
from cosim.scenario.spec import Scenario
from cosim.scenario.tables import problem_message, problem_path
from estimators import ESTIMATORS, ParameterError
from estimators.controller import CONTROLLERS

BUILTIN_DIR = Path(scenarios.__file__).resolve().parent
DEFAULT_SCENARIO = "masses-bias"
#: Limits that keep every derived quantity finite and exact (ticks, t_k in nanoseconds).
MIN_SAMPLE_TIME = 1e-6
MAX_TICKS = 1e9
MAX_NESTING = 32


@dataclass(frozen=True)
class LoadedScenario:
    """A validated scenario with where it came from, its original text and the settings applied
    to it from outside the file (``cosim.scenario.overrides``: path, value)."""

    scenario: Scenario
    source: str
    text: str
    settings: tuple[tuple[str, Any], ...] = ()


def builtin_names(folder: Path = BUILTIN_DIR) -> list[str]:
    return sorted(path.stem for path in folder.glob("*.toml"))


def read_toml_file(target: str, folder: Path, what: str) -> tuple[str, str, Path]:
    """The text of ``target``, a built-in ``what`` (a file of ``folder``) by name or a TOML path, its
    source (``builtin:NAME`` or the path) and its path; one ScenarioError naming the built-in ones
    otherwise."""
    path = Path(target)
    if path.suffix != ".toml" and (folder / f"{target}.toml").exists():
        path, source = folder / f"{target}.toml", f"builtin:{target}"
    elif path.exists():
        source = str(path)
    else:
        known = ", ".join(builtin_names(folder))
        raise ScenarioError(f"no {what} {target!r}: not a file and not a built-in {what} (built-in: {known})")
    try:
        return path.read_text(encoding="utf-8"), source, path
    except (OSError, UnicodeDecodeError) as error:
        raise ScenarioError(f"{source}: cannot read the {what} ({error})") from None


def load(name_or_path: str | Path | None = None) -> LoadedScenario:
    """Load a scenario by built-in name or TOML path (default: the default scenario)."""
    target = DEFAULT_SCENARIO if name_or_path is None else str(name_or_path)
    text, source, _ = read_toml_file(target, BUILTIN_DIR, "scenario")
    return LoadedScenario(scenario=parse(text, source), source=source, text=text)


def parse(text: str, source: str = "<scenario>") -> Scenario:
    """Validate scenario TOML text; raises one ScenarioError listing every problem."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ScenarioError(f"{source}: invalid TOML: {error}") from None
    return validate(data, source)


def validate(data: dict[str, Any], source: str) -> Scenario:
    """Validate scenario data (a file's TOML, parsed); raises one ScenarioError listing every problem."""
    if (deep := _too_deep(data)) is not None:
        raise ScenarioError(
            f"{source}: {deep}: nested more than {MAX_NESTING} tables or lists deep; a scenario needs "
            f"far fewer (flatten the sum of waveforms)"
        )
    try:
        scenario = Scenario.model_validate(data)
    except ValidationError as error:
        problems = [f"{problem_path(e['loc'], data)}: {problem_message(e)}" for e in error.errors()]
        raise ScenarioError(_report(source, problems)) from None
    problems = check(scenario)
    if problems:
        raise ScenarioError(_report(source, problems))
    return scenario


def _too_deep(data: Any, path: str = "", depth: int = 0) -> str | None:
    """The path of a value nested deeper than MAX_NESTING (None if none is): checked before
    pydantic, whose validation would recurse that deep."""
    if depth > MAX_NESTING:
        return path or "(top level)"
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list) else ()
    for key, value in items:
        if isinstance(value, (dict, list)):
            found = _too_deep(
                value, f"{path}[{key}]" if isinstance(key, int) else f"{path}.{key}" if path else str(key), depth + 1
            )
            if found is not None:
                return found
    return None


def _report(source: str, problems: list[str]) -> str:
    if len(problems) == 1:
        return f"{source}: {problems[0]}"
    return f"{source}: {len(problems)} problems:\n" + "\n".join(f"  - {p}" for p in problems)


def check(s: Scenario) -> list[str]:
    """The problems that need the plant's names and the scenario as a whole."""
    problems: list[str] = []
    if s.plant.state_space is not None and s.plant.model != statespace.NAME:
        return [f'plant.state_space: only used with plant.model = "{statespace.NAME}" (got {s.plant.model!r})']
    try:
        info = s.plant_info
    except KeyError as error:
        alternative = f", or {statespace.NAME!r} with a [plant.state_space] table"
        alternative = "" if s.plant.model == statespace.NAME else alternative
        return [f"plant.model: {error.args[0]}{alternative}"]
    sensor_names = [c.name for c in info.sensors]
    actuator_names = [c.name for c in info.actuators]
    state_names = [c.name for c in info.states]

    def unknown(field: str, names: list[str], known: list[str], what: str) -> None:
        for name in names:
            if name not in known:
                close = difflib.get_close_matches(name, known, n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                problems.append(f"{field}: {info.name} has no {what} {name!r}{hint}; it has: {', '.join(known)}")

    if s.sample_time < MIN_SAMPLE_TIME:
        problems.append(
            f"sample_time: {s.sample_time:g} s is below {MIN_SAMPLE_TIME:g} s, the shortest tick the runner keeps"
        )
        return problems
    if s.duration / s.sample_time > MAX_TICKS:
        problems.append(
            f"duration: {s.duration:g} s at sample_time {s.sample_time:g} s makes {s.duration / s.sample_time:.3g} "
            f"ticks; at most {MAX_TICKS:g} (a shorter duration, or a longer sample time)"
        )
        return problems
    if s.sample_time > s.duration:
        problems.append(f"sample_time: {s.sample_time} s is longer than the duration {s.duration} s")
    elif abs(s.duration / s.sample_time - round(s.duration / s.sample_time)) > 1e-9 * s.duration / s.sample_time:
        n = s.duration / s.sample_time
        below, above = math.floor(n) * s.sample_time, math.ceil(n) * s.sample_time
        problems.append(
            f"duration: {s.duration} s is not a whole number of sample times ({s.sample_time} s); use {below:g} or "
            f"{above:g}"
        )
    if s.plant.sensors is not None:
        unknown("plant.sensors", s.plant.sensors, sensor_names, "sensor")
        if len(set(s.plant.sensors)) != len(s.plant.sensors):
            problems.append("plant.sensors: a sensor is listed twice")
    unknown("plant.initial_state", list(s.plant.initial_state), state_names, "state")
    transmitted = list(s.sensors)
    seen_inputs: set[str] = set()
    for i, spec in enumerate(s.inputs):
        unknown(f"inputs[{i}].actuator", [spec.actuator], actuator_names, "actuator")
        if spec.actuator in seen_inputs:
            problems.append(f"inputs[{i}].actuator: {spec.actuator!r} already has an input signal")
        seen_inputs.add(spec.actuator)
    disturbance_names = [c.name for c in info.disturbances]
    seen_inputs.clear()
    for i, disturbance in enumerate(s.disturbances):
        if disturbance.model:
            models = sorted(info.disturbance_models)
            if disturbance.model not in models:
                problems.append(
                    f"disturbances[{i}].model: {info.name} has no disturbance model {disturbance.model!r}"
                    f"{'; it has: ' + ', '.join(models) if models else ''}"
                )
            else:
                try:
                    info.disturbance_models[disturbance.model](np.random.default_rng(0), **disturbance.params)
                except (TypeError, ValueError) as error:
                    problems.append(f"disturbances[{i}].params: {error}")
            continue
        unknown(f"disturbances[{i}].input", [disturbance.input], disturbance_names, "disturbance input")
        if disturbance.input in seen_inputs:
            problems.append(f"disturbances[{i}].input: {disturbance.input!r} already has a signal")
        seen_inputs.add(disturbance.input)
    for group, entries in (("noise", s.noise), ("faults", s.faults)):
        for i, fault in enumerate(entries):
            field = f"{group}[{i}]"
            if isinstance(fault, OnBus):
                problems += _check_bus_fault(s, field, fault)
                continue
            names, what = (
                (actuator_names, "actuator") if fault.acts_on == "actuators" else (transmitted, "transmitted sensor")
            )
            channels = fault.targets if fault.targets is not None else names
            unknown(f"{field}.{fault.acts_on}", channels, names, what)
            _lengths(problems, field, fault, len(channels), fault.per_channel)
            for key in ("std", "bound", "magnitude"):
                if any(v < 0 for v in getattr(fault, key, None) or []):
                    problems.append(f"{field}.{key}: must be non-negative")
    noise_labels, fault_labels = s.fault_labels()
    labels = noise_labels + fault_labels
    for label in sorted({label for label in labels if labels.count(label) > 1}):
        problems.append(f"faults: two noise models or faults are labelled {label!r}; give them distinct names")
    diagnostic_names = sorted(
        {
            d.name
            for e in s.estimators
            if e.kind in ESTIMATORS
            for d in ESTIMATORS[e.kind].diagnostic_channels(tuple(state_names), tuple(transmitted))
        }
    )
    for table, known, what in (
        ("sensors", transmitted, "transmitted sensor"),
        ("actuators", actuator_names, "actuator"),
        ("states", state_names + diagnostic_names, "state or estimator diagnostic"),
    ):
        overrides = getattr(s.bus, table)
        unknown(f"bus.{table}", list(overrides), known, what)
    estimator_names = [e.name for e in s.estimators] + [c.name for c in s.clients]
    for i, client in enumerate(s.clients):
        if estimator_names.count(client.name) > 1:
            problems.append(f"clients[{i}].name: {client.name!r} is also the name of an estimator or another client")
        for j, signal in enumerate(client.signals):
            if not signal.minimum < signal.maximum:
                problems.append(f"clients[{i}].signals[{j}]: minimum must be below maximum")

    def kind_problem(where: str, kind: str, params: dict, registry: dict, what: str) -> str | None:
        """The problem with a participant's kind (with the near one) or its params, if any."""
        if kind not in registry:
            close = difflib.get_close_matches(kind, list(registry), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            return f"{where}.kind: unknown {what} {kind!r}{hint}; known: {', '.join(sorted(registry))}"
        try:
            registry[kind].check_params(params)
        except ParameterError as error:
            return f"{where}.params.{error}"
        return None

    for i, estimator in enumerate(s.estimators):
        if problem := kind_problem(f"estimators[{i}]", estimator.kind, estimator.params, ESTIMATORS, "estimator"):
            problems.append(problem)
        if estimator_names.count(estimator.name) > 1:
            problems.append(f"estimators[{i}].name: {estimator.name!r} is used by two estimators")
    for name in estimator_names:
        if name == "controller":
            problems.append("estimators: the name 'controller' is the controller node's; choose another name")
    if (c := s.controller) is not None:
        if problem := kind_problem("controller", c.kind, c.params, CONTROLLERS, "controller"):
            problems.append(problem)
        diagnosis = next((e for e in s.estimators if e.name == c.diagnosis), None)
        if c.diagnosis and diagnosis is None:
            problems.append(f"controller.diagnosis: {c.diagnosis!r} is not an estimator of this scenario")
        reports = CONTROLLERS[c.kind].reports if c.kind in CONTROLLERS else ()
        if reports and not c.diagnosis:
            problems.append(
                f"controller.diagnosis: {c.kind} reads {', '.join(reports)} from a diagnosis node; name one of the "
                "estimators"
            )
        elif reports and diagnosis is not None and diagnosis.kind in ESTIMATORS:
            published = {
                d.name for d in ESTIMATORS[diagnosis.kind].diagnostic_channels(tuple(state_names), tuple(transmitted))
            }
            missing = [name for name in reports if name not in published]
            if missing:
                problems.append(
                    f"controller.diagnosis: {c.diagnosis!r} ({diagnosis.kind}) does not publish {', '.join(missing)}, "
                    f"which {c.kind} reads; choose a diagnosis estimator that does (e.g. kind cofd)"
                )
        if s.inputs:
            problems.append(
                "inputs: the controller commands every actuator; remove [[inputs]] (or the [controller] table)"
            )
    if not problems:
        problems += _check_bus(s)
    return problems


def _check_bus_fault(s: Scenario, field: str, fault: OnBus) -> list[str]:
    """A bus fault acts on frames the runner sends: the sensors' and, in open loop, the commands'."""
    try:
        codec = s.codec()
    except (ScenarioError, CodecError):
        return []  # reported by _check_bus
    senders = (PLANT,) if s.controller is not None else (PLANT, CONTROLLER)
    runner = {spec.name: spec for spec in codec.specs.values() if spec.sender in senders and spec.channels}
    known = ", ".join(runner)
    problems = []
    names = list(getattr(fault, "messages", None) or []) + ([fault.message] if hasattr(fault, "message") else [])
    key = "messages" if hasattr(fault, "messages") else "message"
    for name in names:
        if name not in runner:
            close = difflib.get_close_matches(name, list(runner), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            problems.append(
                f"{field}.{key}: {name!r} is not a message the runner sends{hint}; bus faults act on {known}"
            )
    value = getattr(fault, "value", None)
    if value is not None and len(names) == 1 and names[0] in runner:
        signals = len(runner[names[0]].channels)
        if len(value) != signals:
            problems.append(f"{field}.value: {names[0]} carries {signals} signal(s); give {signals} value(s)")
    kind = getattr(fault, "kind", "")
    if kind == "babbling_node" and s.bus.timing != "arbitrated":
        problems.append(f'{field}: a babbling node needs [bus] timing = "arbitrated" (an ideal bus takes no time)')
    if kind == "bus_off" and getattr(fault, "node", "") == CONTROLLER and s.controller is not None:
        problems.append(f"{field}.node: the controller is a node process in closed loop; bus_off acts on the plant")
    return problems


def _check_bus(s: Scenario) -> list[str]:
    """The bus signals with their overrides must make a valid CAN database; arbitrated timing needs
    lockstep (its schedule is computed from every answer of a tick), and the traffic it carries
    ids of its own."""
    try:
        codec = s.codec()
    except (ScenarioError, CodecError) as error:
        return [str(error)]
    problems = []
    if s.bus.timing == "arbitrated" and s.timing.mode != "lockstep":
        problems.append(
            'bus.timing: "arbitrated" needs [timing] mode = "lockstep" (the wire is scheduled from every '
            'answer of a tick); use mode = "lockstep" or timing = "ideal"'
        )
    if s.bus.authentication == "secoc":
        problems += _check_secoc(s)
    if s.bus.traffic and s.bus.timing != "arbitrated":
        problems.append('bus.traffic: periodic traffic needs [bus] timing = "arbitrated" (an ideal bus takes no time)')
    taken = {spec.frame_id: spec.name for spec in codec.specs.values()}
    for i, traffic in enumerate(s.bus.traffic):
        if traffic.id in taken:
            problems.append(
                f"bus.traffic[{i}].id: 0x{traffic.id:03X} is {taken[traffic.id]}'s id in this run's database; "
                "give the traffic an id no message uses"
            )
        if not s.bus.fd and traffic.length > 8:
            problems.append(f"bus.traffic[{i}].length: {traffic.length} bytes needs fd = true (classic CAN: 8 at most)")
        taken[traffic.id] = f"bus.traffic[{i}]"
    return problems


def _check_secoc(s: Scenario) -> list[str]:
    """SecOC needs CAN FD (room for the trailer) and nodes the runner gives their keys to."""
    if not s.bus.fd:
        return [
            'bus.authentication: "secoc" needs CAN FD (the 4-byte trailer does not fit classic frames); '
            'set [bus] fd = true or authentication = "none"'
        ]
    external = [f"estimators.{e.name}" for e in s.estimators if e.external]
    external += ["controller"] if s.controller is not None and s.controller.external else []
    external += [f"clients.{c.name}" for c in s.clients]
    if external:
        return [
            f'bus.authentication: "secoc" gives each node its keys in the spec the runner starts it with; '
            f"{external[0]} is started by hand and would have none: run it as a node of the runner, or "
            'authentication = "none"'
        ]
    return []


def _lengths(problems: list[str], field: str, spec: Any, channels: int, keys: tuple[str, ...]) -> None:
    for key in keys:
        value = getattr(spec, key, None)
        if value is not None and len(value) not in (1, channels):
            problems.append(
                f"{field}.{key}: has {len(value)} values for {channels} channels; give one per channel (or one for all)"
            )
