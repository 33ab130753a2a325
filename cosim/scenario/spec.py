"""The scenario's tables: plant, inputs, disturbances, noise and faults, bus, timing, estimators,
clients and controller, and what a validated scenario derives from them (ticks, signals, its CAN
database)."""

from __future__ import annotations

import functools
import json
import math
import warnings
from dataclasses import replace
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationError, field_validator, model_validator

import mjcf
from cosim.bus.codec import Codec
from cosim.bus.secoc import secure_dbc
from cosim.bus.signals import Channel
from cosim.errors import ScenarioError
from cosim.plant import fmu_model, mjcf_file, statespace
from cosim.scenario.faults import FaultSpec, NoiseSpec
from cosim.scenario.tables import Identifier, NonNegative, Positive, Strict, problem_message, problem_path
from cosim.scenario.waveforms import WaveformSpec
from estimators import ESTIMATORS, Diagnostic
from estimators.controller import CONTROLLERS


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
        for field_name, names, size in (
            ("states", self.states, n),
            ("inputs", self.inputs, m),
            ("outputs", self.outputs, p),
            ("disturbances", self.disturbances, nd),
        ):
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


# FmuSpec's key "validate" shadows BaseModel.validate, pydantic 1's deprecated name: harmless, not worth a warning.
warnings.filterwarnings("ignore", message='Field name "validate" in "FmuSpec" shadows', category=UserWarning)


class FmuSpec(Strict):
    """An FMU plant's settings (``plant.model = "plant.fmu"``, docs/fmi.md)."""

    interface: Literal["co-simulation", "model-exchange"] | None = None
    """Which of the FMU's interfaces runs it; default co-simulation if it has one."""
    parameters: dict[str, float | bool | list[float]] = {}
    """Parameter values by variable name (an array parameter as a list, row-major)."""
    states: list[str] | None = None
    """Variables (outputs, locals) that are the truth's states; default the continuous states."""
    disturbances: list[str] = []
    """Inputs that are unknown inputs driven by [[disturbances]], not actuators on the bus."""
    tolerance: Positive | None = None
    """Relative tolerance of the model-exchange solver (and of co-simulation); default the FMU's
    default experiment's, else 1e-5 for model exchange (FMPy's)."""
    bound: float = Field(default=1e3, gt=0)
    """Bus range ±bound of a signal whose variable declares no min/max (classic CAN)."""
    resolution: float = Field(default=1e-6, gt=0)
    """Bus resolution of the Float signals (classic CAN)."""
    validate: bool = True  # type: ignore[assignment]
    """Check the FMU's modelDescription.xml against the FMI schema; false runs one that breaks it."""
    isolation: Literal["process", "none"] = "process"
    """Where the FMU runs: in a process of its own (a hang, crash or print of the FMU cannot harm
    the run), or in the runner's ("none": for an exported FMU's embedded plant, and measurements)."""

    @field_validator("parameters", mode="before")
    @classmethod
    def _dotted(cls, value: Any) -> Any:
        """Nested tables are a dotted name: TOML reads ``mass.m = 3`` (and ``--set
        plant.fmu.parameters.mass.m=3``) as ``mass = { m = 3 }``; a Modelica name is ``mass.m``."""
        if not isinstance(value, dict):
            return value
        flat: dict[str, Any] = {}
        for key, item in value.items():
            if isinstance(item, dict):
                flat |= {f"{key}.{name}": inner for name, inner in cls._dotted(item).items()}
            else:
                flat[key] = item
        return flat


class MjcfSpec(Strict):
    """A plant of the user's own MJCF file's settings (``plant.model = "robot.xml"``, docs/extending.md)."""

    disturbances: list[str] = []
    """Actuators that are unknown inputs driven by [[disturbances]], not inputs on the bus."""
    keyframe: str = ""
    """The keyframe of the initial state and the design point; default the model's first, or qpos0."""
    bound: float = Field(default=1e3, gt=0)
    """Bus range ±bound of the signals ([bus.sensors], [bus.states], [bus.actuators] override it)."""
    resolution: float = Field(default=1e-6, gt=0)
    """Bus resolution of the signals in classic CAN."""


class PlantSpec(Strict):
    model: str
    """A registered MJCF plant (``cosim scenarios`` lists them), "state-space" with
    [plant.state_space], an MJCF file (``*.xml``) or an FMU file (``*.fmu``), each a path relative
    to the scenario file."""
    state_space: StateSpaceSpec | None = None
    """The plant's matrices (model "state-space"), or an FMU plant's design model."""
    fmu: FmuSpec | None = None
    mjcf: MjcfSpec | None = None
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
            raise ValueError(
                "give either input and signal (one unknown input) or model (a random environment of the plant)"
            )
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


class TrafficSpec(Strict):
    """A node outside the estimation loop that keeps the bus busy: one frame of ``length`` bytes on
    ``id`` every ``period`` seconds from ``start`` to ``end`` (payloads drawn from the run's seed).
    Its frames occupy the simulated wire (``timing = "arbitrated"``) and the log; they are not put
    on the run's python-can channel, where nobody would read them."""

    name: Identifier
    id: Annotated[int, Field(ge=0, le=0x7FF)]
    period: Positive
    length: Annotated[int, Field(ge=0, le=64)] = 8
    start: NonNegative = 0.0
    end: Annotated[float, Field(allow_inf_nan=True)] = math.inf


class BusSpec(Strict):
    interface: Literal["udp_multicast", "socketcan", "virtual"] = "udp_multicast"
    channel: str = ""
    """udp_multicast: the multicast group (default: a fresh host-only group per run); socketcan: the
    interface (default vcan0); virtual: the channel name (default: a fresh one)."""
    port: Annotated[int, Field(ge=0, le=65535)] = 0
    """udp_multicast: the UDP port (default 0: a free port per run)."""
    mirror: bool = False
    """udp_multicast: every frame also goes alone, in python-can's own format, to a second group on
    the run's port, for programs that can only open python-can's ``udp_multicast`` (on the run's own
    group each participant sends its frames of a tick in one datagram, which only ``cosim_udp`` reads)."""
    allow_network: bool = False
    """udp_multicast: allow a channel whose frames can leave this host (a link-local or wider group);
    set by whoever runs the scenario (``--allow-network``), refused in a scenario file."""
    fd: bool = False
    bitrate: Annotated[int, Field(gt=0)] = 500_000
    data_bitrate: Annotated[int, Field(gt=0)] = 2_000_000
    sensors: dict[str, ChannelOverride] = {}
    actuators: dict[str, ChannelOverride] = {}
    states: dict[str, ChannelOverride] = {}
    timing: Literal["ideal", "arbitrated"] = "ideal"
    """ideal: every frame of a tick arrives at once; arbitrated: frames go one at a time at the bit
    rate, lowest id first, and arrive at their last bit, late if after the next tick (docs/bus.md)."""
    traffic: list[TrafficSpec] = []
    """Periodic frames of other nodes that load the bus (arbitrated timing only)."""
    authentication: Literal["none", "secoc"] = "none"
    """secoc (CAN FD): every data frame carries a freshness value and a truncated AES-CMAC of its
    sender, and receivers drop what fails (docs/bus.md)."""
    intrusion_detector: bool = False
    """A key-less intrusion detector in the runner: per-id period and sequence checks, DBC ranges,
    unknown senders; its verdicts on /cosim/ids, scored like a diagnosis (docs/bus.md)."""


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

    def channel(self) -> Channel:
        return Channel(self.name, self.unit, self.description, self.minimum, self.maximum, self.resolution)


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
        ``interface``, ``channel``, ``port``, ``allow_network``, ``mirror`` of [bus] and ``mode``,
        ``speed`` of [timing]
        (None keeps a value)."""
        data = self.model_dump()
        tables = {
            "interface": "bus",
            "channel": "bus",
            "port": "bus",
            "allow_network": "bus",
            "mirror": "bus",
            "mode": "timing",
            "speed": "timing",
        }
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
            raise ScenarioError(
                "; ".join(f"{problem_path(e['loc'], data)}: {problem_message(e)}" for e in error.errors())
            ) from None

    @classmethod
    def from_resolved(cls, text: str) -> Scenario:
        """The scenario a log records as resolved JSON (``model_dump_json``); a ValueError if this
        version cannot read it."""
        return cls.model_validate(_without_nulls(json.loads(text)))

    def fault_labels(self) -> tuple[list[str], list[str]]:
        """Labels of the noise models and of the faults: their name, or kind and position."""
        noise = [spec.name or f"noise{i}" for i, spec in enumerate(self.noise)]
        faults = [spec.name or f"{spec.kind}{i}" for i, spec in enumerate(self.faults)]
        return noise, faults

    def codec(self) -> Codec:
        """The run's CAN database: its sensors, actuators, estimators and clients on its bus. One
        built for each distinct database and shared (``_database``), as ``Codec.from_dbc`` shares
        its codecs: a campaign's runs, and the grid points its loading checks, differ in their
        faults and seeds, not in their frames, and a database costs some 15 ms to build."""
        sensors, actuators, states = self.channels()

        def frozen(channels: dict[str, list[Channel]]) -> tuple[tuple[str, tuple[Channel, ...]], ...]:
            return tuple((name, tuple(each)) for name, each in channels.items())

        controller = self.controller_channels()
        return _database(
            tuple(sensors),
            tuple(actuators),
            frozen({e.name: states if ESTIMATORS[e.kind].estimates else [] for e in self.estimators}),
            frozen(self.diagnostic_channels()),
            frozen(self.client_channels()),
            None if controller is None else tuple(controller),
            self.bus.fd,
            self.bus.bitrate,
            self.bus.data_bitrate,
            self.sample_time,
            self.bus.authentication == "secoc" and self.bus.fd,  # classic CAN: refused by the scenario checks
        )

    def estimator_diagnostics(self, kind: str) -> list[Diagnostic]:
        """The diagnostics an estimator of ``kind`` publishes in this scenario (a KindError if the
        kind does not resolve)."""
        return ESTIMATORS[kind].diagnostic_channels(self.states, self.sensors)

    def controller_diagnostics(self, kind: str) -> list[Diagnostic]:
        """The diagnostics a controller of ``kind`` publishes in this scenario."""
        return CONTROLLERS[kind].diagnostic_channels(self.actuators, self.sensors)

    def diagnostic_channels(self) -> dict[str, list[Channel]]:
        """Each estimator's diagnostics as bus signals ([bus.states] overrides apply to them too)."""
        return {e.name: self._bus_signals(self.estimator_diagnostics(e.kind)) for e in self.estimators}

    def controller_channels(self) -> list[Channel] | None:
        """The controller node's diagnostics as bus signals, or None for open-loop inputs."""
        if self.controller is None:
            return None
        return self._bus_signals(self.controller_diagnostics(self.controller.kind))

    def _bus_signals(self, diagnostics: list[Diagnostic]) -> list[Channel]:
        signals = (Channel(d.name, d.unit, d.description, -d.bound, d.bound, d.resolution) for d in diagnostics)
        return [_override(signal, self.bus.states, "states") for signal in signals]

    def client_channels(self) -> dict[str, list[Channel]]:
        return {c.name: [signal.channel() for signal in c.signals] for c in self.clients}

    def channels(self) -> tuple[list[Channel], list[Channel], list[Channel]]:
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
        if fmu_model.is_fmu(self.plant.model):
            return self.fmu_model().info()
        if mjcf_file.is_mjcf(self.plant.model):
            return mjcf_file.plant_info(self.plant.model, self.plant.mjcf or MjcfSpec())
        if self.plant.model == statespace.NAME:
            if self.plant.state_space is None:
                raise KeyError('plant.model "state-space" needs a [plant.state_space] table with A, B and C')
            return statespace.plant_info(self.plant.state_space)
        return mjcf.get(self.plant.model)

    def fmu_model(self) -> fmu_model.FmuModel:
        """An FMU plant's variables as signals under its [plant.fmu] table (FmuError if it cannot be
        the plant)."""
        return fmu_model.read(self.plant.model, self.plant.fmu or FmuSpec())

    @property
    def sensors(self) -> tuple[str, ...]:
        return (
            tuple(self.plant.sensors)
            if self.plant.sensors is not None
            else tuple(s.name for s in self.plant_info.sensors)
        )

    @property
    def states(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.plant_info.states)

    @property
    def actuators(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.plant_info.actuators)

    @property
    def disturbance_inputs(self) -> tuple[str, ...]:
        return tuple(d.name for d in self.plant_info.disturbances)


def _override(channel: Channel, overrides: dict[str, ChannelOverride], table: str) -> Channel:
    spec = overrides.get(channel.name)
    if spec is None:
        return channel
    try:
        return replace(channel, **{k: v for k, v in spec.model_dump().items() if v is not None})
    except ValueError as error:
        raise ScenarioError(f"bus.{table}.{channel.name}: {error.args[0].split(': ', 1)[-1]}") from None


def _without_nulls(data: Any) -> Any:
    """Resolved JSON without its null fields, which then take their defaults: JSON has no
    infinity, so a fault without an end (end = inf, the default) was written as null."""
    if isinstance(data, dict):
        return {key: _without_nulls(value) for key, value in data.items() if value is not None}
    if isinstance(data, list):
        return [_without_nulls(value) for value in data]
    return data


@functools.lru_cache(maxsize=64)
def _database(
    sensors: tuple[Channel, ...],
    actuators: tuple[Channel, ...],
    estimators: tuple[tuple[str, tuple[Channel, ...]], ...],
    diagnostics: tuple[tuple[str, tuple[Channel, ...]], ...],
    clients: tuple[tuple[str, tuple[Channel, ...]], ...],
    controller: tuple[Channel, ...] | None,
    fd: bool,
    bitrate: int,
    data_bitrate: int,
    cycle_time: float,
    secured: bool,
) -> Codec:
    """``Scenario.codec``'s codecs, by what makes their database (a codec is read-only to its users)."""
    codec = Codec(
        list(sensors),
        list(actuators),
        {name: list(channels) for name, channels in estimators},
        diagnostics={name: list(channels) for name, channels in diagnostics},
        clients={name: list(channels) for name, channels in clients},
        controller=None if controller is None else list(controller),
        fd=fd,
        bitrate=bitrate,
        data_bitrate=data_bitrate,
        cycle_time=cycle_time,
    )
    return Codec.from_dbc(secure_dbc(codec.dbc)) if secured else codec
