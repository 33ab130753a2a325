"""Scenarios: one TOML file names the plant, timing, inputs, noise, faults, bus and estimators.

Loading validates everything that can be checked without running MuJoCo: unknown keys, wrong
types and shapes, impossible values, names that the plant does not have. All problems are
reported together in one ScenarioError, each naming its field (``faults[0].value``) and the fix.

A scalar may stand for a vector (it applies to every channel) and a number for a waveform (a
constant). Waveforms are tables with a ``kind``: constant, sine, square, ramp, exponential, sum.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Discriminator, Field, ValidationError, model_validator

import faults as fm
import mjcf
import scenarios
from cosim.plant import statespace
from cosim.bus.codec import Codec
from cosim.errors import CodecError, ScenarioError
from estimators import ESTIMATORS, ParameterError
from estimators.controller import CONTROLLERS

BUILTIN_DIR = Path(scenarios.__file__).resolve().parent
DEFAULT_SCENARIO = "masses-bias"

Identifier = Annotated[str, Field(pattern=r"^[A-Za-z][A-Za-z0-9_]{0,23}$")]
NonNegative = Annotated[float, Field(ge=0)]
Positive = Annotated[float, Field(gt=0)]
Probability = Annotated[float, Field(ge=0, le=1)]


def _as_list(value: Any) -> Any:
    """A single number or table stands for a one-element list (applied to every channel)."""
    return [value] if isinstance(value, (int, float, dict)) and not isinstance(value, bool) else value


def _as_waveform(value: Any) -> Any:
    return {"kind": "constant", "value": value} if isinstance(value, (int, float)) and not isinstance(value, bool) else value


#: A list of numbers; a single number applies to every channel.
Vector = Annotated[list[float], BeforeValidator(_as_list)]


class Strict(BaseModel):
    """A table whose keys are all known; an unknown key is reported with the allowed ones."""

    model_config = ConfigDict(frozen=True, strict=True, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        if isinstance(data, dict):
            allowed = list(cls.model_fields)
            for key in data:
                if key not in allowed:
                    close = difflib.get_close_matches(str(key), allowed, n=1)
                    hint = f" (did you mean {close[0]!r}?)" if close else ""
                    raise ValueError(f"unknown key {key!r}{hint}; allowed keys: {', '.join(allowed)}")
        return data


# -- waveforms --------------------------------------------------------------------------------


class ConstantSpec(Strict):
    kind: Literal["constant"]
    value: float


class SineSpec(Strict):
    kind: Literal["sine"]
    amplitude: float
    frequency: NonNegative
    phase: float = 0.0
    offset: float = 0.0


class SquareSpec(Strict):
    kind: Literal["square"]
    amplitude: float
    frequency: Positive
    duty: Annotated[float, Field(gt=0, lt=1)] = 0.5
    offset: float = 0.0


class RampSpec(Strict):
    kind: Literal["ramp"]
    slope: float
    offset: float = 0.0


class ExponentialSpec(Strict):
    kind: Literal["exponential"]
    rate: float
    initial: float = 1.0
    final: float = 0.0


class SumSpec(Strict):
    kind: Literal["sum"]
    terms: list[WaveformSpec] = Field(min_length=1)


WaveformSpec = Annotated[
    Union[ConstantSpec, SineSpec, SquareSpec, RampSpec, ExponentialSpec, SumSpec],
    Discriminator("kind"),
    BeforeValidator(_as_waveform),
]
SumSpec.model_rebuild()


def build_waveform(spec: Any) -> fm.Waveform:
    if isinstance(spec, SumSpec):
        return fm.Sum(tuple(build_waveform(term) for term in spec.terms))
    cls = {
        "constant": fm.Constant, "sine": fm.Sine, "square": fm.Square, "ramp": fm.Ramp, "exponential": fm.Exponential,
    }[spec.kind]
    return cls(**spec.model_dump(exclude={"kind"}))


# -- noise and faults -------------------------------------------------------------------------


class Windowed(Strict):
    name: Identifier | None = None
    start: NonNegative = 0.0
    end: Annotated[float, Field(allow_inf_nan=True)] = math.inf

    @model_validator(mode="after")
    def _window(self) -> Windowed:
        if not self.end > self.start:
            raise ValueError(f"end ({self.end}) must be after start ({self.start})")
        return self


class OnSensors(Windowed):
    sensors: list[str] | None = None
    """Sensors affected, by name; default: every transmitted sensor."""


class BiasSpec(OnSensors):
    kind: Literal["bias"]
    value: Vector
    amplitude: WaveformSpec = ConstantSpec(kind="constant", value=1.0)


class DriftSpec(OnSensors):
    kind: Literal["drift"]
    rate: Vector


class GainSpec(OnSensors):
    kind: Literal["gain"]
    gain: Annotated[list[WaveformSpec], BeforeValidator(_as_list)]


class GaussianNoiseSpec(OnSensors):
    kind: Literal["gaussian_noise"]
    std: Annotated[Vector, Field(min_length=1)]


class UniformNoiseSpec(OnSensors):
    kind: Literal["uniform_noise"]
    bound: Annotated[Vector, Field(min_length=1)]


class StuckSpec(OnSensors):
    kind: Literal["stuck"]
    value: Vector | None = None


class DropoutSpec(OnSensors):
    kind: Literal["dropout"]
    probability: Probability


class OutliersSpec(OnSensors):
    kind: Literal["outliers"]
    probability: Probability
    magnitude: Vector


class ActuatorEffectivenessSpec(Windowed):
    kind: Literal["actuator_effectiveness"]
    actuators: list[str] | None = None
    effectiveness: Annotated[list[WaveformSpec], BeforeValidator(_as_list)]


class ActuatorOffsetSpec(Windowed):
    """Additive actuator fault u ← u + g(t − start)·value (the f_a of the course notes' eq. (11))."""

    kind: Literal["actuator_offset"]
    actuators: list[str] | None = None
    value: Vector
    amplitude: WaveformSpec = ConstantSpec(kind="constant", value=1.0)


NoiseSpec = Annotated[Union[GaussianNoiseSpec, UniformNoiseSpec], Discriminator("kind")]
FaultSpec = Annotated[
    Union[
        BiasSpec, DriftSpec, GainSpec, GaussianNoiseSpec, UniformNoiseSpec, StuckSpec, DropoutSpec, OutliersSpec,
        ActuatorEffectivenessSpec, ActuatorOffsetSpec,
    ],
    Discriminator("kind"),
]

# -- the rest ---------------------------------------------------------------------------------


class StateSpaceSpec(Strict):
    """A plant given by its matrices (``plant.model = "state-space"``): ẋ = A x + B u + E d (or
    x⁺ = A x + B u + E d with ``time = "discrete"``, one step per sample), y = C x + D u, with
    known inputs u and unknown inputs (disturbances) d."""

    time: Literal["continuous", "discrete"] = "continuous"
    A: list[list[float]]
    B: list[list[float]]
    C: list[list[float]]
    D: list[list[float]] | None = None
    E: list[list[float]] | None = None
    """Unknown-input matrix, one column per disturbance; driven by [[disturbances]]."""
    states: list[str] | None = None
    """State names; default x1, x2, …"""
    inputs: list[str] | None = None
    """Input (actuator) names; default u1, u2, …"""
    outputs: list[str] | None = None
    """Output (sensor) names; default y1, y2, …"""
    disturbances: list[str] | None = None
    """Unknown input names; default d1, d2, …"""
    unit: str = ""
    bound: float = Field(1e3, gt=0)
    """Bus range ±bound of every signal (classic CAN)."""
    resolution: float = Field(1e-6, gt=0)
    """Bus resolution of every signal (classic CAN)."""

    @model_validator(mode="after")
    def _shapes(self) -> StateSpaceSpec:
        n = len(self.A)
        problems = []
        if n == 0 or any(len(row) != n for row in self.A):
            problems.append("A must be square (a list of n rows of n numbers)")
        m = len(self.B[0]) if self.B else 0
        if len(self.B) != n or m == 0 or any(len(row) != m for row in self.B):
            problems.append(f"B must have {n} rows of equally many numbers (one column per input)")
        p = len(self.C)
        if p == 0 or any(len(row) != n for row in self.C):
            problems.append(f"C must have rows of {n} numbers (one row per output)")
        if self.D is not None and (len(self.D) != p or any(len(row) != m for row in self.D)):
            problems.append(f"D must have {p} rows of {m} numbers")
        nd = len(self.E[0]) if self.E else 0
        if self.E is not None and (len(self.E) != n or nd == 0 or any(len(row) != nd for row in self.E)):
            problems.append(f"E must have {n} rows of equally many numbers (one column per disturbance)")
        for field_name, names, size in (("states", self.states, n), ("inputs", self.inputs, m), ("outputs", self.outputs, p),
                                        ("disturbances", self.disturbances, nd)):
            if names is not None and (len(names) != size or len(set(names)) != size):
                problems.append(f"{field_name} must name {size} distinct signals")
        if problems:
            raise ValueError("; ".join(problems))
        return self

    @property
    def state_names(self) -> list[str]:
        return self.states or [f"x{i + 1}" for i in range(len(self.A))]

    @property
    def input_names(self) -> list[str]:
        return self.inputs or [f"u{i + 1}" for i in range(len(self.B[0]))]

    @property
    def output_names(self) -> list[str]:
        return self.outputs or [f"y{i + 1}" for i in range(len(self.C))]

    @property
    def disturbance_names(self) -> list[str]:
        return self.disturbances or [f"d{i + 1}" for i in range(len(self.E[0]) if self.E else 0)]


class PlantSpec(Strict):
    model: str
    """A registered MJCF plant (``cosim scenarios`` lists them), or "state-space" with [plant.state_space]."""
    state_space: StateSpaceSpec | None = None
    sensors: list[str] | None = None
    """Transmitted sensors, in order; default: all the plant declares."""
    initial_state: dict[str, float] = {}
    """Initial state components by name; the others come from the plant's keyframe."""


class InputSpec(Strict):
    actuator: str
    signal: WaveformSpec


class DisturbanceSpec(Strict):
    """An unknown input of the plant (``plant.disturbances`` of its module, or the columns of E of
    a state-space plant) and its signal, or one of the plant's random environments (``model``, a
    seeded generator of all its unknown inputs at once, e.g. a sea state) with its ``params``;
    logged as truth, never sent on the bus. Several add up."""

    input: str = ""
    signal: WaveformSpec | None = None
    model: str = ""
    params: dict[str, Any] = {}

    @model_validator(mode="after")
    def _one_form(self) -> DisturbanceSpec:
        if bool(self.model) == bool(self.input or self.signal is not None):
            raise ValueError("give either input and signal (one unknown input) or model (a random environment of the plant)")
        if self.input and self.signal is None:
            raise ValueError("input needs a signal")
        if self.signal is not None and not self.input:
            raise ValueError("signal needs an input")
        if self.params and not self.model:
            raise ValueError("params belong to a model")
        return self


class ChannelOverride(Strict):
    minimum: float | None = None
    maximum: float | None = None
    resolution: Positive | None = None


class BusSpec(Strict):
    interface: Literal["udp_multicast", "socketcan", "virtual"] = "udp_multicast"
    channel: str = ""
    """udp_multicast: the multicast group (default: a fresh host-only group per run); socketcan: the
    interface (default vcan0); virtual: the channel name (default: a fresh one)."""
    port: Annotated[int, Field(ge=0, le=65535)] = 0
    """udp_multicast: the UDP port (default 0: a free port per run)."""
    fd: bool = False
    bitrate: Annotated[int, Field(gt=0)] = 500_000
    data_bitrate: Annotated[int, Field(gt=0)] = 2_000_000
    sensors: dict[str, ChannelOverride] = {}
    actuators: dict[str, ChannelOverride] = {}
    states: dict[str, ChannelOverride] = {}


class TimingSpec(Strict):
    mode: Literal["lockstep", "realtime"] = "lockstep"
    """lockstep: each tick waits for every node's answer (deterministic); realtime: ticks follow
    the wall clock and late answers are counted as deadline misses."""
    speed: Positive = 1.0
    """realtime: simulated seconds per wall-clock second."""
    node_timeout: Positive = 10.0
    """lockstep: a node that does not answer a tick within this many seconds is reported as hung."""
    join_timeout: Positive = 30.0
    """How long to wait for nodes and declared clients to join before tick 0."""


class SignalSpec(Strict):
    name: Identifier
    unit: str = ""
    description: str = ""
    minimum: float
    maximum: float
    resolution: Positive

    def channel(self) -> mjcf.Channel:
        return mjcf.Channel(self.name, self.unit, self.description, self.minimum, self.maximum, self.resolution)


class ClientSpec(Strict):
    """A program that joins the run's bus on its own (written with ``cosim.bus.client``)."""

    name: Identifier
    lockstep: bool = True
    """The runner waits for it to join before tick 0 and for its heartbeat every tick."""
    signals: list[SignalSpec] = []
    """The signals it publishes, packed into CLIENT_<name> messages of the DBC."""


class EstimatorSpec(Strict):
    name: Identifier
    kind: str
    params: dict[str, Any] = {}
    external: bool = False
    """Do not start this node: it is started by hand with 'cosim node NAME' (e.g. in a debugger)."""


class ControllerSpec(Strict):
    """A feedback controller closing the loop over the bus (the ``controller`` node): it commands
    every actuator from the sensor readings, in place of open-loop [[inputs]]."""

    kind: str
    params: dict[str, Any] = {}
    diagnosis: str = ""
    """An estimator whose diagnostics (the controller kind's reports, e.g. a fault mask) the
    controller reads, one tick late."""
    external: bool = False
    """Do not start the node: it is started by hand with 'cosim node controller'."""


class Scenario(Strict):
    name: Annotated[str, Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")]
    description: str = ""
    seed: Annotated[int, Field(ge=0)] = 0
    duration: Positive
    sample_time: Positive
    plant: PlantSpec
    inputs: list[InputSpec] = []
    disturbances: list[DisturbanceSpec] = []
    noise: list[NoiseSpec] = []
    faults: list[FaultSpec] = []
    bus: BusSpec = BusSpec()
    timing: TimingSpec = TimingSpec()
    estimators: list[EstimatorSpec] = []
    clients: list[ClientSpec] = []
    controller: ControllerSpec | None = None

    @property
    def ticks(self) -> int:
        """Ticks k = 0 … N−1 at t_k = k τ, N = duration / τ (a whole number, checked on load)."""
        return max(1, round(self.duration / self.sample_time))

    @property
    def dt_ns(self) -> int:
        """The sample time in nanoseconds; t_k = k · dt_ns exactly."""
        return round(self.sample_time * 1e9)

    def time(self, k: int) -> float:
        """t_k in seconds, as the float nearest to k τ (so that a fault starting at a multiple of τ,
        written as a decimal in the scenario, starts exactly at that tick)."""
        return k * self.dt_ns / 1e9

    def with_seed(self, seed: int | None) -> Scenario:
        """The same scenario with another seed (None keeps it)."""
        return self.with_overrides(seed=seed)

    def with_overrides(self, **changes: Any) -> Scenario:
        """The scenario with command-line overrides, validated like the file: ``seed``, and
        ``interface``, ``channel``, ``port`` of [bus] and ``mode``, ``speed`` of [timing]
        (None keeps a value)."""
        data = self.model_dump()
        tables = {"interface": "bus", "channel": "bus", "port": "bus", "mode": "timing", "speed": "timing"}
        for key, value in changes.items():
            if value is None:
                continue
            if key in tables:
                data[tables[key]][key] = value
            else:
                data[key] = value
        try:
            return Scenario.model_validate(data)
        except ValidationError as error:
            raise ScenarioError("; ".join(f"{_path(e['loc'], data)}: {_message(e)}" for e in error.errors())) from None

    def fault_labels(self) -> tuple[list[str], list[str]]:
        """Labels of the noise models and of the faults: their name, or kind and position."""
        noise = [spec.name or f"noise{i}" for i, spec in enumerate(self.noise)]
        faults = [spec.name or f"{spec.kind}{i}" for i, spec in enumerate(self.faults)]
        return noise, faults

    def codec(self) -> Codec:
        """The run's CAN database: its sensors, actuators, estimators and clients on its bus."""
        sensors, actuators, states = self.channels()
        return Codec(
            sensors, actuators, {e.name: states for e in self.estimators}, diagnostics=self.diagnostic_channels(),
            clients=self.client_channels(), controller=self.controller_channels(), fd=self.bus.fd,
            bitrate=self.bus.bitrate, data_bitrate=self.bus.data_bitrate, cycle_time=self.sample_time,
        )

    def diagnostic_channels(self) -> dict[str, list[mjcf.Channel]]:
        """Each estimator's diagnostics as bus signals ([bus.states] overrides apply to them too)."""
        states = tuple(c.name for c in self.plant_info.states)
        return {
            e.name: [
                _override(mjcf.Channel(d.name, d.unit, d.description, -d.bound, d.bound, d.resolution), self.bus.states, "states")
                for d in ESTIMATORS[e.kind].diagnostic_channels(states, self.sensors)
            ]
            for e in self.estimators
        }

    def controller_channels(self) -> list[mjcf.Channel] | None:
        """The controller node's diagnostics as bus signals, or None for open-loop inputs."""
        if self.controller is None:
            return None
        return [
            _override(mjcf.Channel(d.name, d.unit, d.description, -d.bound, d.bound, d.resolution), self.bus.states, "states")
            for d in CONTROLLERS[self.controller.kind].diagnostic_channels(self.actuators, self.sensors)
        ]

    def client_channels(self) -> dict[str, list[mjcf.Channel]]:
        return {c.name: [signal.channel() for signal in c.signals] for c in self.clients}

    def channels(self) -> tuple[list[mjcf.Channel], list[mjcf.Channel], list[mjcf.Channel]]:
        """The transmitted sensors, the actuators and the states as bus signals, with the [bus]
        overrides of their range and resolution applied."""
        info = self.plant_info
        return (
            [_override(info.sensor(n), self.bus.sensors, "sensors") for n in self.sensors],
            [_override(info.actuator(n), self.bus.actuators, "actuators") for n in self.actuators],
            [_override(c, self.bus.states, "states") for c in info.states],
        )

    @property
    def plant_info(self) -> mjcf.PlantInfo:
        if self.plant.model == statespace.NAME:
            if self.plant.state_space is None:
                raise KeyError('plant.model "state-space" needs a [plant.state_space] table with A, B and C')
            return statespace.plant_info(self.plant.state_space)
        return mjcf.get(self.plant.model)

    @property
    def sensors(self) -> tuple[str, ...]:
        return tuple(self.plant.sensors) if self.plant.sensors is not None else tuple(s.name for s in self.plant_info.sensors)

    @property
    def actuators(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.plant_info.actuators)

    @property
    def disturbance_inputs(self) -> tuple[str, ...]:
        return tuple(d.name for d in self.plant_info.disturbances)


def _override(channel: mjcf.Channel, overrides: dict[str, ChannelOverride], table: str) -> mjcf.Channel:
    spec = overrides.get(channel.name)
    if spec is None:
        return channel
    try:
        return replace(channel, **{k: v for k, v in spec.model_dump().items() if v is not None})
    except ValueError as error:
        raise ScenarioError(f"bus.{table}.{channel.name}: {error.args[0].split(': ', 1)[-1]}") from None


# -- loading ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class LoadedScenario:
    """A validated scenario with where it came from and its original text."""

    scenario: Scenario
    source: str
    text: str


def builtin_names() -> list[str]:
    return sorted(path.stem for path in BUILTIN_DIR.glob("*.toml"))


def load(name_or_path: str | Path | None = None) -> LoadedScenario:
    """Load a scenario by built-in name or TOML path (default: the default scenario)."""
    target = DEFAULT_SCENARIO if name_or_path is None else str(name_or_path)
    path = Path(target)
    if path.suffix != ".toml" and (BUILTIN_DIR / f"{target}.toml").exists():
        path, source = BUILTIN_DIR / f"{target}.toml", f"builtin:{target}"
    elif path.exists():
        source = str(path)
    else:
        known = ", ".join(builtin_names())
        raise ScenarioError(f"no scenario {target!r}: not a file and not a built-in scenario (built-in: {known})")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise ScenarioError(f"{source}: cannot read the scenario ({error})") from None
    return LoadedScenario(scenario=parse(text, source), source=source, text=text)


def parse(text: str, source: str = "<scenario>") -> Scenario:
    """Validate scenario TOML text; raises one ScenarioError listing every problem."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ScenarioError(f"{source}: invalid TOML: {error}") from None
    try:
        scenario = Scenario.model_validate(data)
    except ValidationError as error:
        problems = [f"{_path(e['loc'], data)}: {_message(e)}" for e in error.errors()]
        raise ScenarioError(_report(source, problems)) from None
    problems = check(scenario)
    if problems:
        raise ScenarioError(_report(source, problems))
    return scenario


def _report(source: str, problems: list[str]) -> str:
    if len(problems) == 1:
        return f"{source}: {problems[0]}"
    return f"{source}: {len(problems)} problems:\n" + "\n".join(f"  - {p}" for p in problems)


def _path(loc: tuple[Any, ...], data: Any) -> str:
    """A readable field path, without the union tags pydantic inserts (``faults[0].bias.value``
    becomes ``faults[0].value``): a tag is the first item that names the current table's kind."""
    parts: list[str] = []
    node, tag_pending = data, True
    for item in loc:
        if not isinstance(node, (dict, list)) and parts:
            break  # a number standing for a table (a constant waveform): the number is the culprit
        if isinstance(item, int):
            parts.append(f"[{item}]")
            node = node[item] if isinstance(node, list) and item < len(node) else None
        elif tag_pending and isinstance(node, dict) and node.get("kind") == item:
            tag_pending = False
            continue
        else:
            parts.append(f".{item}" if parts else str(item))
            node = node.get(item) if isinstance(node, dict) else None
        tag_pending = True
    return "".join(parts) or "(top level)"


def _message(error: dict[str, Any]) -> str:
    kind = error["type"]
    if kind == "missing":
        return "required but missing"
    if kind == "union_tag_invalid":
        tags = error.get("ctx", {}).get("expected_tags", "")
        return f"unknown kind {error['input'].get('kind')!r}; expected one of {tags}"
    if kind == "union_tag_not_found":
        return "needs a 'kind' key"
    if kind in ("model_attributes_type", "dict_type"):
        return f"expected a table (where a waveform is expected, a number also works), got {error['input']!r}"
    message = error["msg"]
    return message.removeprefix("Value error, ")


def check(s: Scenario) -> list[str]:
    """The problems that need the plant's names and the scenario as a whole."""
    problems: list[str] = []
    if s.plant.state_space is not None and s.plant.model != statespace.NAME:
        return [f'plant.state_space: only used with plant.model = "{statespace.NAME}" (got {s.plant.model!r})']
    try:
        info = s.plant_info
    except KeyError as error:
        return [f"plant.model: {error.args[0]}{'' if s.plant.model == statespace.NAME else f', or {statespace.NAME!r} with a [plant.state_space] table'}"]
    sensor_names = [c.name for c in info.sensors]
    actuator_names = [c.name for c in info.actuators]
    state_names = [c.name for c in info.states]

    def unknown(field: str, names: list[str], known: list[str], what: str) -> None:
        for name in names:
            if name not in known:
                close = difflib.get_close_matches(name, known, n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                problems.append(f"{field}: {info.name} has no {what} {name!r}{hint}; it has: {', '.join(known)}")

    if s.sample_time > s.duration:
        problems.append(f"sample_time: {s.sample_time} s is longer than the duration {s.duration} s")
    elif abs(s.duration / s.sample_time - round(s.duration / s.sample_time)) > 1e-9 * s.duration / s.sample_time:
        n = s.duration / s.sample_time
        below, above = math.floor(n) * s.sample_time, math.ceil(n) * s.sample_time
        problems.append(f"duration: {s.duration} s is not a whole number of sample times ({s.sample_time} s); use {below:g} or {above:g}")
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
    for i, spec in enumerate(s.disturbances):
        if spec.model:
            models = sorted(info.disturbance_models)
            if spec.model not in models:
                problems.append(f"disturbances[{i}].model: {info.name} has no disturbance model {spec.model!r}"
                                f"{'; it has: ' + ', '.join(models) if models else ''}")
            else:
                try:
                    info.disturbance_models[spec.model](np.random.default_rng(0), **spec.params)
                except (TypeError, ValueError) as error:
                    problems.append(f"disturbances[{i}].params: {error}")
            continue
        unknown(f"disturbances[{i}].input", [spec.input], disturbance_names, "disturbance input")
        if spec.input in seen_inputs:
            problems.append(f"disturbances[{i}].input: {spec.input!r} already has a signal")
        seen_inputs.add(spec.input)
    for group, specs in (("noise", s.noise), ("faults", s.faults)):
        for i, spec in enumerate(specs):
            field = f"{group}[{i}]"
            if isinstance(spec, (ActuatorEffectivenessSpec, ActuatorOffsetSpec)):
                channels = spec.actuators if spec.actuators is not None else actuator_names
                unknown(f"{field}.actuators", channels, actuator_names, "actuator")
                _lengths(problems, field, spec, len(channels), ("effectiveness", "value"))
            else:
                channels = spec.sensors if spec.sensors is not None else transmitted
                unknown(f"{field}.sensors", channels, transmitted, "transmitted sensor")
                _lengths(problems, field, spec, len(channels), ("value", "rate", "gain", "std", "bound", "magnitude"))
                for key in ("std", "bound", "magnitude"):
                    if any(v < 0 for v in getattr(spec, key, None) or []):
                        problems.append(f"{field}.{key}: must be non-negative")
    noise_labels, fault_labels = s.fault_labels()
    labels = noise_labels + fault_labels
    for label in sorted({label for label in labels if labels.count(label) > 1}):
        problems.append(f"faults: two noise models or faults are labelled {label!r}; give them distinct names")
    diagnostic_names = sorted({
        d.name for e in s.estimators if e.kind in ESTIMATORS
        for d in ESTIMATORS[e.kind].diagnostic_channels(tuple(state_names), tuple(transmitted))
    })
    for table, known, what in (("sensors", transmitted, "transmitted sensor"), ("actuators", actuator_names, "actuator"),
                               ("states", state_names + diagnostic_names, "state or estimator diagnostic")):
        overrides = getattr(s.bus, table)
        unknown(f"bus.{table}", list(overrides), known, what)
    estimator_names = [e.name for e in s.estimators] + [c.name for c in s.clients]
    for i, spec in enumerate(s.clients):
        if estimator_names.count(spec.name) > 1:
            problems.append(f"clients[{i}].name: {spec.name!r} is also the name of an estimator or another client")
        for j, signal in enumerate(spec.signals):
            if not signal.minimum < signal.maximum:
                problems.append(f"clients[{i}].signals[{j}]: minimum must be below maximum")
    for i, spec in enumerate(s.estimators):
        if spec.kind not in ESTIMATORS:
            close = difflib.get_close_matches(spec.kind, list(ESTIMATORS), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            problems.append(f"estimators[{i}].kind: unknown estimator {spec.kind!r}{hint}; known: {', '.join(sorted(ESTIMATORS))}")
        else:
            try:
                ESTIMATORS[spec.kind].check_params(spec.params)
            except ParameterError as error:
                problems.append(f"estimators[{i}].params.{error}")
        if estimator_names.count(spec.name) > 1:
            problems.append(f"estimators[{i}].name: {spec.name!r} is used by two estimators")
    for name in estimator_names:
        if name == "controller":
            problems.append("estimators: the name 'controller' is the controller node's; choose another name")
    if (c := s.controller) is not None:
        if c.kind not in CONTROLLERS:
            close = difflib.get_close_matches(c.kind, list(CONTROLLERS), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            problems.append(f"controller.kind: unknown controller {c.kind!r}{hint}; known: {', '.join(sorted(CONTROLLERS))}")
        else:
            try:
                CONTROLLERS[c.kind].check_params(c.params)
            except ParameterError as error:
                problems.append(f"controller.params.{error}")
        diagnosis = next((e for e in s.estimators if e.name == c.diagnosis), None)
        if c.diagnosis and diagnosis is None:
            problems.append(f"controller.diagnosis: {c.diagnosis!r} is not an estimator of this scenario")
        reports = CONTROLLERS[c.kind].reports if c.kind in CONTROLLERS else ()
        if reports and not c.diagnosis:
            problems.append(f"controller.diagnosis: {c.kind} reads {', '.join(reports)} from a diagnosis node; name one of the estimators")
        elif reports and diagnosis is not None and diagnosis.kind in ESTIMATORS:
            published = {d.name for d in ESTIMATORS[diagnosis.kind].diagnostic_channels(tuple(state_names), tuple(transmitted))}
            missing = [name for name in reports if name not in published]
            if missing:
                problems.append(f"controller.diagnosis: {c.diagnosis!r} ({diagnosis.kind}) does not publish {', '.join(missing)}, "
                                f"which {c.kind} reads; choose a diagnosis estimator that does (e.g. kind cofd)")
        if s.inputs:
            problems.append("inputs: the controller commands every actuator; remove [[inputs]] (or the [controller] table)")
    if not problems:
        problems += _check_bus(s)
    return problems


def _check_bus(s: Scenario) -> list[str]:
    """The bus signals with their overrides must make a valid CAN database."""
    try:
        s.codec()
    except (ScenarioError, CodecError) as error:
        return [str(error)]
    return []


def _lengths(problems: list[str], field: str, spec: Any, channels: int, keys: tuple[str, ...]) -> None:
    for key in keys:
        value = getattr(spec, key, None)
        if value is not None and len(value) not in (1, channels):
            problems.append(f"{field}.{key}: has {len(value)} values for {channels} channels; give one per channel (or one for all)")
