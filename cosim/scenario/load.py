"""Loading a scenario: TOML text or a built-in name in, one validated ``Scenario`` or one error out.

Structure and types are checked first (pydantic, ``cosim.scenario.spec``); once those are right,
``check`` looks at the scenario as a whole: names the plant does not have, vector lengths,
estimator and controller parameters, fault labels, the bus signals. Every problem is reported in
one ScenarioError, each naming its field (``faults[0].value``) and the fix.
"""

from __future__ import annotations

import difflib
import importlib.util
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

import scenarios
from cosim.bus.codec import CONTROLLER, PLANT
from cosim.errors import CodecError, ModelError, ScenarioError
from cosim.kinds import KindError, Kinds, is_file_reference
from cosim.plant import statespace
from cosim.plant.fmu_model import FmuError, is_fmu
from cosim.plant.mjcf_file import is_mjcf
from cosim.scenario.faults import OnBus
from cosim.scenario.spec import Scenario
from cosim.scenario.tables import loads_toml, problem_message, problem_path
from estimators import ESTIMATORS, ParameterError
from estimators.controller import CONTROLLERS
from mjcf import PlantInfo

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


def folder_of(source: str) -> Path:
    """The folder that paths in a scenario from ``source`` are relative to: the file's, the
    built-in scenarios' for ``builtin:NAME``, else the working directory."""
    if source.startswith("builtin:"):
        return BUILTIN_DIR
    path = Path(source)
    return path.parent if path.is_file() else Path.cwd()


def parse(text: str, source: str = "<scenario>", folder: Path | None = None) -> Scenario:
    """Validate scenario TOML text; raises one ScenarioError listing every problem. Paths in it
    (an FMU plant's) are relative to ``folder`` (default: ``folder_of(source)``)."""
    try:
        data = loads_toml(text)
    except tomllib.TOMLDecodeError as error:
        raise ScenarioError(f"{source}: invalid TOML: {error}") from None
    return validate(data, source, folder)


def validate(data: dict[str, Any], source: str, folder: Path | None = None) -> Scenario:
    """Validate scenario data (a file's TOML, parsed); raises one ScenarioError listing every
    problem. An FMU plant's path becomes absolute, relative to ``folder`` (default: ``folder_of(source)``)."""
    if (deep := _too_deep(data)) is not None:
        raise ScenarioError(
            f"{source}: {deep}: nested more than {MAX_NESTING} tables or lists deep; a scenario needs "
            f"far fewer (flatten the sum of waveforms)"
        )
    data = _absolute_paths(data, folder if folder is not None else folder_of(source))
    try:
        scenario = Scenario.model_validate(data)
    except ValidationError as error:
        problems = [f"{problem_path(e['loc'], data)}: {problem_message(e)}" for e in error.errors()]
        raise ScenarioError(_report(source, problems)) from None
    problems = check(scenario)
    if scenario.bus.allow_network:  # a file someone hands you must not open their bus to the network
        problems.append(
            "bus.allow_network: a scenario file cannot widen the bus beyond this host; whoever runs it "
            "decides that, with cosim run --allow-network (or allow_network=True in cosim.api.run)"
        )
    if problems:
        raise ScenarioError(_report(source, problems))
    return scenario


def _absolute_paths(data: dict[str, Any], folder: Path) -> dict[str, Any]:
    """The data with its relative file paths made absolute against ``folder``: an FMU or MJCF
    plant's model file, and the Python file of an estimator's, a fault's or the controller's kind
    (``observers.py:ClassName``); the scenario then means the same files wherever it is run from,
    in node processes and on campaign workers too, and its resolved JSON in a log names them."""

    def absolute(path: str) -> str:
        return path if Path(path).is_absolute() else str((folder / path).resolve())

    def kind(entry: Any) -> Any:
        if not isinstance(entry, dict) or not isinstance(entry.get("kind"), str):
            return entry
        if is_file_reference(entry["kind"]):
            file, _, name = entry["kind"].partition(":")
            return {**entry, "kind": f"{absolute(file)}:{name}"}
        beside = _module_beside(entry["kind"], folder)
        return {**entry, "kind": beside} if beside is not None else entry

    data = dict(data)
    plant = data.get("plant")
    if (
        isinstance(plant, dict)
        and isinstance(plant.get("model"), str)
        and (is_fmu(plant["model"]) or is_mjcf(plant["model"]))
    ):
        data["plant"] = {**plant, "model": absolute(plant["model"])}
    for tables in ("estimators", "faults"):
        if isinstance(data.get(tables), list):
            data[tables] = [kind(entry) for entry in data[tables]]
    if "controller" in data:
        data["controller"] = kind(data["controller"])
    return data


def _module_beside(kind: str, folder: Path) -> str | None:
    """A module path kind (``myobs:Cls``, ``pkg.myobs:Cls``) whose module is not on the import path
    but next to the scenario (``myobs.py``, ``pkg/myobs.py`` in its folder), as that file's
    reference; None for any other kind (the import path comes first, as Python's own lookup)."""
    module, colon, attribute = kind.partition(":")
    if not colon or not all(part.isidentifier() for part in module.split(".")):
        return None
    file = folder.joinpath(*module.split(".")).with_suffix(".py")
    if not file.is_file():
        return None
    try:
        if importlib.util.find_spec(module) is not None:
            return None
    except (ImportError, ValueError):  # a parent package that does not import: not on the import path
        pass
    return f"{file.resolve()}:{attribute}"


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
    fmu = is_fmu(s.plant.model)
    if s.plant.state_space is not None and s.plant.model != statespace.NAME and not fmu:
        return [
            f'plant.state_space: only used with plant.model = "{statespace.NAME}" or an FMU (got {s.plant.model!r})'
        ]
    if s.plant.fmu is not None and not fmu:
        return [f'plant.fmu: only used with an FMU plant (plant.model = "….fmu", got {s.plant.model!r})']
    if s.plant.mjcf is not None and not is_mjcf(s.plant.model):
        return [f'plant.mjcf: only used with an MJCF file plant (plant.model = "….xml", got {s.plant.model!r})']
    try:
        info = s.plant_info
    except (FmuError, ModelError) as error:
        return [str(error)]
    except KeyError as error:
        alternative = f", or {statespace.NAME!r} with a [plant.state_space] table"
        alternative = "" if s.plant.model == statespace.NAME else alternative
        return [f"plant.model: {error.args[0]}{alternative}"]
    if ticks := _tick_limits(s):
        return ticks
    names = _Names(info, s)
    kinds = _Participants(s)
    problems = [
        *_duration(s),
        *_plant_signals(s, names),
        *(_design_model(s, names) if fmu and s.plant.state_space is not None else []),
        *_inputs(s, names),
        *_disturbances(s, names),
        *_faults(s, names),
        *_labels(s),
        *_bus_overrides(s, names, kinds),
        *_clients(s),
        *kinds.problems,
        *_controller(s, kinds),
    ]
    return problems or _check_bus(s)


@dataclass(frozen=True)
class _Names:
    """The plant's names a scenario may refer to, and how to say that one is not among them."""

    info: PlantInfo
    scenario: Scenario

    def unknown(self, field: str, names: list[str], known: list[str], what: str) -> list[str]:
        problems = []
        for name in names:
            if name not in known:
                close = difflib.get_close_matches(name, known, n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                problems.append(f"{field}: {self.info.name} has no {what} {name!r}{hint}; it has: {', '.join(known)}")
        return problems

    def driven_once(self, driven: list[tuple[str, str]], known: list[str], what: str, signal: str) -> list[str]:
        """Each (field, name) a known signal, and none given two."""
        problems, seen = [], set()
        for field, name in driven:
            problems += self.unknown(field, [name], known, what)
            if name in seen:
                problems.append(f"{field}: {name!r} already has {signal}")
            seen.add(name)
        return problems

    @property
    def sensors(self) -> list[str]:
        return [c.name for c in self.info.sensors]

    @property
    def transmitted(self) -> list[str]:
        return list(self.scenario.sensors)

    @property
    def actuators(self) -> list[str]:
        return [c.name for c in self.info.actuators]

    @property
    def states(self) -> list[str]:
        return [c.name for c in self.info.states]

    @property
    def disturbances(self) -> list[str]:
        return [c.name for c in self.info.disturbances]


class _Participants:
    """The scenario's estimator and controller kinds, resolved once (None: a kind that does not
    resolve), with the problems of their kinds, parameters and names."""

    def __init__(self, s: Scenario) -> None:
        self.problems: list[str] = []
        self.estimators: list[Any] = []
        names = [e.name for e in s.estimators] + [c.name for c in s.clients]
        for i, e in enumerate(s.estimators):
            self.estimators.append(self._resolve(f"estimators[{i}]", e.kind, e.params, ESTIMATORS))
            if names.count(e.name) > 1:
                self.problems.append(f"estimators[{i}].name: {e.name!r} is used by two estimators")
        for name in names:
            if name == "controller":
                self.problems.append("estimators: the name 'controller' is the controller node's; choose another name")
        c = s.controller
        self.controller = None if c is None else self._resolve("controller", c.kind, c.params, CONTROLLERS)

    def _resolve(self, where: str, kind: str, params: dict[str, Any], registry: Kinds[Any]) -> Any:
        """The class of a participant's kind, or None, noting the problem with it or its params."""
        try:
            cls = registry[kind]
        except KindError as error:
            self.problems.append(f"{where}.kind: {error}")
            return None
        try:
            cls.check_params(params)
        except ParameterError as error:
            self.problems.append(f"{where}.params.{error}")
        return cls

    def published(self, s: Scenario, index: int) -> list[str]:
        """The names of the diagnostics the scenario's estimator ``index`` publishes (none if its
        kind does not resolve)."""
        if self.estimators[index] is None:
            return []
        return [d.name for d in s.estimator_diagnostics(s.estimators[index].kind)]


def _tick_limits(s: Scenario) -> list[str]:
    """A sample time or a number of ticks the runner cannot keep exact (nothing else is checked then)."""
    if s.sample_time < MIN_SAMPLE_TIME:
        return [f"sample_time: {s.sample_time:g} s is below {MIN_SAMPLE_TIME:g} s, the shortest tick the runner keeps"]
    if s.duration / s.sample_time > MAX_TICKS:
        return [
            f"duration: {s.duration:g} s at sample_time {s.sample_time:g} s makes {s.duration / s.sample_time:.3g} "
            f"ticks; at most {MAX_TICKS:g} (a shorter duration, or a longer sample time)"
        ]
    return []


def _duration(s: Scenario) -> list[str]:
    if s.sample_time > s.duration:
        return [f"sample_time: {s.sample_time} s is longer than the duration {s.duration} s"]
    n = s.duration / s.sample_time
    if abs(n - round(n)) > 1e-9 * n:
        below, above = math.floor(n) * s.sample_time, math.ceil(n) * s.sample_time
        return [
            f"duration: {s.duration} s is not a whole number of sample times ({s.sample_time} s); use {below:g} or "
            f"{above:g}"
        ]
    return []


def _plant_signals(s: Scenario, names: _Names) -> list[str]:
    problems = []
    if s.plant.sensors is not None:
        problems += names.unknown("plant.sensors", s.plant.sensors, names.sensors, "sensor")
        if len(set(s.plant.sensors)) != len(s.plant.sensors):
            problems.append("plant.sensors: a sensor is listed twice")
    return problems + names.unknown("plant.initial_state", list(s.plant.initial_state), names.states, "state")


def _design_model(s: Scenario, names: _Names) -> list[str]:
    """An FMU plant's design model names the FMU's states, actuators and disturbances, in order,
    and outputs that include the transmitted sensors."""
    spec = s.plant.state_space
    assert spec is not None
    problems = [
        f"plant.state_space.{field}: the design model's {field} must be the FMU's, in order: {', '.join(known) or '[]'}"
        for field, given, known in (
            ("states", spec.state_names, names.states),
            ("inputs", spec.input_names, names.actuators),
            ("disturbances", spec.disturbance_names, names.disturbances),
        )
        if list(given) != list(known)
    ]
    missing = [name for name in names.transmitted if name not in spec.output_names]
    if missing:
        problems.append(f"plant.state_space.outputs: the design model has no output for {', '.join(missing)}")
    return problems


def _inputs(s: Scenario, names: _Names) -> list[str]:
    driven = [(f"inputs[{i}].actuator", spec.actuator) for i, spec in enumerate(s.inputs)]
    return names.driven_once(driven, names.actuators, "actuator", "an input signal")


def _disturbances(s: Scenario, names: _Names) -> list[str]:
    problems: list[str] = []
    models = names.info.disturbance_models
    for i, disturbance in enumerate(s.disturbances):
        if disturbance.model and disturbance.model not in models:
            problems.append(
                f"disturbances[{i}].model: {names.info.name} has no disturbance model {disturbance.model!r}"
                f"{'; it has: ' + ', '.join(sorted(models)) if models else ''}"
            )
        elif disturbance.model:
            try:
                models[disturbance.model](np.random.default_rng(0), **disturbance.params)
            except (TypeError, ValueError) as error:
                problems.append(f"disturbances[{i}].params: {error}")
    driven = [(f"disturbances[{i}].input", d.input) for i, d in enumerate(s.disturbances) if not d.model]
    return problems + names.driven_once(driven, names.disturbances, "disturbance input", "a signal")


def _faults(s: Scenario, names: _Names) -> list[str]:
    problems: list[str] = []
    for group, entries in (("noise", s.noise), ("faults", s.faults)):
        for i, fault in enumerate(entries):
            field = f"{group}[{i}]"
            if isinstance(fault, OnBus):
                problems += _check_bus_fault(s, field, fault)
                continue
            known, what = (
                (names.actuators, "actuator")
                if fault.acts_on == "actuators"
                else (names.transmitted, "transmitted sensor")
            )
            channels = fault.targets if fault.targets is not None else known
            problems += names.unknown(f"{field}.{fault.acts_on}", channels, known, what)
            _lengths(problems, field, fault, len(channels), fault.per_channel)
            for key in ("std", "bound", "magnitude"):
                if any(v < 0 for v in getattr(fault, key, None) or []):
                    problems.append(f"{field}.{key}: must be non-negative")
    return problems


def timing_warnings(s: Scenario) -> list[str]:
    """Faults that never happen: those that start at or after the run's last tick."""
    end = (s.ticks - 1) * s.sample_time
    return [
        f"faults[{i}] ({fault.name or fault.kind}) starts at {fault.start:g} s, after the run's last tick "
        f"(t = {end:g} s): it never happens; start it earlier or lengthen the run (duration = {s.duration:g})"
        for i, fault in enumerate(s.faults)
        if fault.start > end + 1e-9 * max(1.0, end)
    ]


def _labels(s: Scenario) -> list[str]:
    noise_labels, fault_labels = s.fault_labels()
    labels = noise_labels + fault_labels
    return [
        f"faults: two noise models or faults are labelled {label!r}; give them distinct names"
        for label in sorted({label for label in labels if labels.count(label) > 1})
    ]


def _bus_overrides(s: Scenario, names: _Names, kinds: _Participants) -> list[str]:
    diagnostics = sorted({name for i in range(len(s.estimators)) for name in kinds.published(s, i)})
    problems = []
    for table, known, what in (
        ("sensors", names.transmitted, "transmitted sensor"),
        ("actuators", names.actuators, "actuator"),
        ("states", names.states + diagnostics, "state or estimator diagnostic"),
    ):
        problems += names.unknown(f"bus.{table}", list(getattr(s.bus, table)), known, what)
    return problems


def _clients(s: Scenario) -> list[str]:
    problems = []
    names = [e.name for e in s.estimators] + [c.name for c in s.clients]
    for i, client in enumerate(s.clients):
        if names.count(client.name) > 1:
            problems.append(f"clients[{i}].name: {client.name!r} is also the name of an estimator or another client")
        for j, signal in enumerate(client.signals):
            if not signal.minimum < signal.maximum:
                problems.append(f"clients[{i}].signals[{j}]: minimum must be below maximum")
    return problems


def _controller(s: Scenario, kinds: _Participants) -> list[str]:
    """A controller that reads a diagnosis node's reports needs one that publishes them; one that
    commands the actuators leaves no room for open-loop inputs."""
    c = s.controller
    if c is None:
        return []
    problems = []
    diagnosis = next((i for i, e in enumerate(s.estimators) if e.name == c.diagnosis), None)
    if c.diagnosis and diagnosis is None:
        problems.append(f"controller.diagnosis: {c.diagnosis!r} is not an estimator of this scenario")
    reports = kinds.controller.reports if kinds.controller is not None else ()
    if reports and not c.diagnosis:
        problems.append(
            f"controller.diagnosis: {c.kind} reads {', '.join(reports)} from a diagnosis node; name one of the "
            "estimators"
        )
    elif reports and diagnosis is not None and kinds.estimators[diagnosis] is not None:
        missing = [name for name in reports if name not in kinds.published(s, diagnosis)]
        if missing:
            problems.append(
                f"controller.diagnosis: {c.diagnosis!r} ({s.estimators[diagnosis].kind}) does not publish "
                f"{', '.join(missing)}, which {c.kind} reads; choose a diagnosis estimator that does (e.g. kind cofd)"
            )
    if s.inputs:
        problems.append("inputs: the controller commands every actuator; remove [[inputs]] (or the [controller] table)")
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
    key = ("params." if hasattr(fault, "params") else "") + ("messages" if hasattr(fault, "messages") else "message")
    for name in names:
        if name not in runner:
            close = difflib.get_close_matches(name, list(runner), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            problems.append(
                f"{field}.{key}: {name!r} is not a message the runner sends{hint}; bus faults act on {known}"
            )
    for key in ("value", "offset", "rate"):
        value = getattr(fault, key, None)
        if value is not None and (key == "value" or value) and len(names) == 1 and names[0] in runner:
            signals = len(runner[names[0]].channels)
            if len(value) != signals:
                problems.append(f"{field}.{key}: {names[0]} carries {signals} signal(s); give {signals} value(s)")
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
