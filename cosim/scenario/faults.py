"""Noise and fault tables, and the fault models they build.

A fault kind is two classes: its table here (the keys a scenario gives, validated) and its model in
``faults.models``, which registers itself under the same ``kind``. ``build_faults`` turns a
scenario's tables into models through that registry: a table's ``parameters`` are the model's
keyword arguments beside its channels and window.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import fields as dataclass_fields
from typing import Annotated, Any, ClassVar, Literal, get_args

from pydantic import BeforeValidator, Discriminator, Field, Tag, field_validator, model_validator

import faults as fm
from cosim.scenario.tables import (
    PLUGIN_BUS_TAG,
    PLUGIN_TAG,
    Identifier,
    NonNegative,
    Probability,
    Strict,
    Vector,
    as_list,
)
from cosim.scenario.waveforms import ConstantSpec, WaveformSpec, build_waveform


def _widen(values: Sequence[Any], n: int) -> tuple[Any, ...]:
    """One value per channel: a single value stands for all n."""
    return tuple(values) * n if len(values) == 1 else tuple(values)


class Windowed(Strict):
    """A fault or noise model active on [start, end)."""

    name: Identifier | None = None
    start: NonNegative = 0.0
    end: Annotated[float, Field(allow_inf_nan=True)] = math.inf

    @model_validator(mode="after")
    def _window(self) -> Windowed:
        if not self.end > self.start:
            raise ValueError(f"end ({self.end}) must be after start ({self.start})")
        return self

    acts_on: ClassVar[str] = "sensors"
    """Which plant signals it acts on: "sensors" or "actuators"."""
    model_names: ClassVar[dict[str, str]] = {}
    """Keys whose model parameter has another name (key -> parameter)."""

    @property
    def targets(self) -> list[str] | None:
        """The signals it acts on, by name; None: all of them."""
        return getattr(self, self.acts_on)

    @property
    def per_channel(self) -> tuple[str, ...]:
        """The keys that hold one value per channel: the model's per-channel parameters."""
        keys = {parameter: key for key, parameter in self.model_names.items()}
        model = fm.FAULT_MODELS[getattr(self, "kind")]  # noqa: B009 (every concrete table has one)
        return tuple(keys.get(name, name) for name in fm.per_channel_parameters(model))

    def parameters(self, channels: int) -> dict[str, Any]:
        """The fault model's keyword arguments besides its channels, window and label: the table's
        other keys, a waveform built, a list as a tuple, a per-channel one widened to ``channels``."""
        parameters = {}
        for key in type(self).model_fields.keys() - _NOT_PARAMETERS:
            value = _model_value(getattr(self, key))
            if key in self.per_channel and value is not None:
                value = _widen(value, channels)
            parameters[self.model_names.get(key, key)] = value
        return parameters


_NOT_PARAMETERS = {"kind", "name", "start", "end", "sensors", "actuators"}


def _model_value(value: Any) -> Any:
    """A table's value as a fault model takes it (the only tables in a fault's are waveforms)."""
    if isinstance(value, list):
        return tuple(_model_value(item) for item in value)
    return build_waveform(value) if isinstance(value, Strict) else value


class OnSensors(Windowed):
    sensors: list[str] | None = None
    """Sensors affected, by name; default: every transmitted sensor."""


class OnActuators(Windowed):
    acts_on = "actuators"
    actuators: list[str] | None = None
    """Actuators affected, by name; default: every actuator."""


class BiasSpec(OnSensors):
    kind: Literal["bias"]
    value: Vector
    amplitude: WaveformSpec = ConstantSpec(kind="constant", value=1.0)


class DriftSpec(OnSensors):
    kind: Literal["drift"]
    rate: Vector


class GainSpec(OnSensors):
    kind: Literal["gain"]
    gain: Annotated[list[WaveformSpec], BeforeValidator(as_list)]


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


class ActuatorEffectivenessSpec(OnActuators):
    kind: Literal["actuator_effectiveness"]
    effectiveness: Annotated[list[WaveformSpec], BeforeValidator(as_list)]


class ActuatorOffsetSpec(OnActuators):
    """Additive actuator fault u ← u + g(t − start)·value (the f_a of the course notes' eq. (11))."""

    kind: Literal["actuator_offset"]
    value: Vector
    amplitude: WaveformSpec = ConstantSpec(kind="constant", value=1.0)


class OnBus(Windowed):
    """A bus fault (``faults.models.BusFault``): it acts on frames, not on signal values."""

    acts_on = "bus"

    @property
    def targets(self) -> list[str] | None:
        return None


class OnMessages(OnBus):
    messages: Annotated[list[str], Field(min_length=1)]
    """The DBC messages it hits, by name (the runner's: SENSOR_*, and COMMAND_* in open loop)."""

    @property
    def targets(self) -> list[str] | None:
        return list(self.messages)


class FrameLossSpec(OnMessages):
    kind: Literal["frame_loss"]
    probability: Probability
    burst_length: Annotated[float, Field(ge=1.0)] = 1.0
    """Mean frames per burst; 1: every frame lost independently."""


class FrameDelaySpec(OnMessages):
    kind: Literal["frame_delay"]
    delay: NonNegative
    jitter: NonNegative = 0.0


class FrameCorruptionSpec(OnMessages):
    kind: Literal["frame_corruption"]
    probability: Probability
    retransmit: bool = True


class BusOffSpec(OnBus):
    kind: Literal["bus_off"]
    node: Literal["plant", "controller"] = "plant"
    """The node whose transmissions fail: ``plant`` (the sensors) or ``controller`` (open-loop commands)."""
    recover: bool = False

    @property
    def targets(self) -> list[str] | None:
        return [self.node]


class BabblingNodeSpec(OnBus):
    kind: Literal["babbling_node"]
    id: Annotated[int, Field(ge=0, le=0x7FF)] = 0x001
    period: Annotated[float, Field(gt=0.0)] = 0.0001
    length: Annotated[int, Field(ge=0, le=8)] = 8
    model_names = {"id": "frame_id"}

    @property
    def targets(self) -> list[str] | None:
        return [f"0x{self.id:03X}"]


class OnMessage(OnBus):
    message: str
    """The DBC message an intruder sends, by name."""

    @property
    def targets(self) -> list[str] | None:
        return [self.message]


class SpoofingSpec(OnMessage):
    kind: Literal["spoofing"]
    value: Vector
    """The values it sends, one per signal of the message besides ``tick``."""


class ReplaySpec(OnMessage):
    kind: Literal["replay"]
    lag: Annotated[float, Field(gt=0.0)] = 1.0


class SuspensionSpec(OnMessages):
    """The ECU of ``messages`` silenced (``faults.attacks.Suspension``)."""

    kind: Literal["suspension"]


class MasqueradeSpec(OnMessage):
    """The genuine sender of ``message`` suspended and an intruder sending in its place
    (``faults.attacks.Masquerade``): ``value`` if given, else the genuine reading + ``offset`` +
    ``rate`` (t − start)."""

    kind: Literal["masquerade"]
    value: Vector | None = None
    offset: Vector = []
    rate: Vector = []


class FuzzingSpec(OnBus):
    """Random ids in [``low``, ``high``] every ``period``, with ``length`` random bytes or the
    ``payload`` given in hex (``"FFFFFFFFFFFFFFFF"``, ROAD's fuzzing) (``faults.attacks.Fuzzing``)."""

    kind: Literal["fuzzing"]
    low: Annotated[int, Field(ge=0, le=0x7FF)] = 0x000
    high: Annotated[int, Field(ge=0, le=0x7FF)] = 0x7FF
    period: Annotated[float, Field(gt=0.0)] = 0.0005
    length: Annotated[int, Field(ge=0, le=8)] = 8
    payload: str | None = None
    """Every frame's bytes, two hex digits each (up to 8 bytes); none: ``length`` random bytes."""

    @field_validator("payload")
    @classmethod
    def _payload(cls, value: str | None) -> str | None:
        if value is not None and not re.fullmatch(r"([0-9A-Fa-f]{2}){0,8}", value):
            raise ValueError(f"{value!r} is not up to 8 bytes of two hex digits each (e.g. 'FFFFFFFFFFFFFFFF')")
        return value

    def parameters(self, channels: int) -> dict[str, Any]:
        parameters = super().parameters(channels)
        if self.payload is not None:
            parameters["payload"] = bytes.fromhex(self.payload)
        return parameters

    @model_validator(mode="after")
    def _ids(self) -> FuzzingSpec:
        if self.low > self.high:
            raise ValueError(f"low ({self.low:#x}) must not exceed high ({self.high:#x})")
        return self

    @property
    def targets(self) -> list[str] | None:
        return [f"0x{self.low:03X}-0x{self.high:03X}"]


class PluginFaultSpec(Windowed):
    """A fault model from outside cosim: an installed plugin's kind (entry-point group
    ``cosim.faults``) or a class in a file (``kind = "my_faults.py:Stiction"``), a ``SensorFault``
    or an ``ActuatorFault`` dataclass; ``sensors`` or ``actuators`` name what it acts on (default:
    all), ``params`` its parameters (the dataclass's fields, a list for a tuple)."""

    kind: str
    sensors: list[str] | None = None
    actuators: list[str] | None = None
    params: dict[str, Any] = {}

    @model_validator(mode="before")
    @classmethod
    def _known_kind(cls, data: Any) -> Any:
        """An unknown kind is that, not the keys its table would have (checked before them)."""
        from cosim.kinds import KindError

        if isinstance(data, dict) and isinstance(kind := data.get("kind"), str):
            try:
                fm.FAULT_MODELS[kind]
            except KindError as error:
                raise ValueError(str(error)) from None
        return data

    @model_validator(mode="after")
    def _contract(self) -> PluginFaultSpec:
        model = fm.FAULT_MODELS[self.kind]
        if not issubclass(model, (fm.SensorFault, fm.ActuatorFault)):
            raise ValueError(f"fault {self.kind!r} is a {model.__name__}: not a sensor, actuator or bus fault")
        wrong, right = ("sensors", "actuators") if issubclass(model, fm.ActuatorFault) else ("actuators", "sensors")
        if getattr(self, wrong) is not None:
            raise ValueError(f"{wrong}: fault {self.kind!r} acts on {right}")
        _check_params(self.kind, model, self.params)
        return self

    @property
    def acts_on(self) -> str:  # type: ignore[override]
        return "actuators" if issubclass(fm.FAULT_MODELS[self.kind], fm.ActuatorFault) else "sensors"

    def parameters(self, channels: int) -> dict[str, Any]:
        return {name: _model_value(value) for name, value in self.params.items()}


class PluginBusFaultSpec(OnBus):
    """A bus fault from outside cosim: a ``BusFault`` dataclass of a plugin or a file
    (``kind = "my_attacks.py:Flipper"``), which the runner decides through the methods of
    ``BusFault`` alone (``cosim.run.busfaults``); ``params`` are its fields (``messages``, ...)."""

    kind: str
    params: dict[str, Any] = {}

    @model_validator(mode="after")
    def _contract(self) -> PluginBusFaultSpec:
        model = fm.FAULT_MODELS[self.kind]
        _check_params(self.kind, model, self.params)
        return self

    @property
    def messages(self) -> list[str]:
        """The messages it names (``messages``, ``message``), which must be the runner's."""
        named = self.params.get("messages") or []
        return [*named, *([self.params["message"]] if self.params.get("message") else [])]

    @property
    def targets(self) -> list[str] | None:
        return self.messages or None

    def parameters(self, channels: int) -> dict[str, Any]:
        return {name: _model_value(value) for name, value in self.params.items()}


#: The built-in fault tables, each under its kind; any other kind is a plugin's (``PluginFaultSpec``).
BUILTIN_FAULTS = (
    BiasSpec,
    DriftSpec,
    GainSpec,
    GaussianNoiseSpec,
    UniformNoiseSpec,
    StuckSpec,
    DropoutSpec,
    OutliersSpec,
    ActuatorEffectivenessSpec,
    ActuatorOffsetSpec,
    FrameLossSpec,
    FrameDelaySpec,
    FrameCorruptionSpec,
    BusOffSpec,
    BabblingNodeSpec,
    SpoofingSpec,
    ReplaySpec,
    SuspensionSpec,
    MasqueradeSpec,
    FuzzingSpec,
)
_BUILTIN_KINDS = {get_args(table.model_fields["kind"].annotation)[0] for table in BUILTIN_FAULTS}


def _table_of(value: Any) -> str | None:
    """The union member a fault table validates as: its built-in kind, or a plugin's."""
    kind = value.get("kind") if isinstance(value, dict) else getattr(value, "kind", None)
    if kind is None:
        return None
    if kind in _BUILTIN_KINDS:
        return str(kind)
    from cosim.kinds import KindError

    try:
        bus = isinstance(kind, str) and issubclass(fm.FAULT_MODELS[kind], fm.BusFault)
    except KindError:
        bus = False  # PluginFaultSpec says what is wrong with it
    return PLUGIN_BUS_TAG if bus else PLUGIN_TAG


NoiseSpec = Annotated[GaussianNoiseSpec | UniformNoiseSpec, Discriminator("kind")]
FaultSpec = Annotated[
    Annotated[BiasSpec, Tag("bias")]
    | Annotated[DriftSpec, Tag("drift")]
    | Annotated[GainSpec, Tag("gain")]
    | Annotated[GaussianNoiseSpec, Tag("gaussian_noise")]
    | Annotated[UniformNoiseSpec, Tag("uniform_noise")]
    | Annotated[StuckSpec, Tag("stuck")]
    | Annotated[DropoutSpec, Tag("dropout")]
    | Annotated[OutliersSpec, Tag("outliers")]
    | Annotated[ActuatorEffectivenessSpec, Tag("actuator_effectiveness")]
    | Annotated[ActuatorOffsetSpec, Tag("actuator_offset")]
    | Annotated[FrameLossSpec, Tag("frame_loss")]
    | Annotated[FrameDelaySpec, Tag("frame_delay")]
    | Annotated[FrameCorruptionSpec, Tag("frame_corruption")]
    | Annotated[BusOffSpec, Tag("bus_off")]
    | Annotated[BabblingNodeSpec, Tag("babbling_node")]
    | Annotated[SpoofingSpec, Tag("spoofing")]
    | Annotated[ReplaySpec, Tag("replay")]
    | Annotated[SuspensionSpec, Tag("suspension")]
    | Annotated[MasqueradeSpec, Tag("masquerade")]
    | Annotated[FuzzingSpec, Tag("fuzzing")]
    | Annotated[PluginFaultSpec, Tag(PLUGIN_TAG)]
    | Annotated[PluginBusFaultSpec, Tag(PLUGIN_BUS_TAG)],
    Discriminator(_table_of),
]


def build_fault(spec: FaultSpec | OnBus, label: str, sensors: Sequence[str], actuators: Sequence[str]) -> fm.Fault:
    """The fault model of one table, on the transmitted ``sensors`` or the ``actuators`` (or, for a
    bus fault, on frames)."""
    channels: tuple[int, ...] = ()
    if not isinstance(spec, OnBus):
        signals = list(actuators if spec.acts_on == "actuators" else sensors)
        channels = tuple(signals.index(name) for name in (spec.targets if spec.targets is not None else signals))
    model = fm.FAULT_MODELS[getattr(spec, "kind")]  # noqa: B009 (every concrete table has one)
    return model(channels=channels, start=spec.start, end=spec.end, label=label, **spec.parameters(len(channels)))


def build_faults(scenario: Any) -> fm.FaultInjector:
    """The scenario's noise and faults as fault models on its transmitted sensors and actuators."""
    sensors, actuators = scenario.sensors, scenario.actuators
    noise_labels, fault_labels = scenario.fault_labels()
    noise: list[fm.SensorFault] = []
    for spec, label in zip(scenario.noise, noise_labels):
        model = build_fault(spec, label, sensors, actuators)
        if not isinstance(model, fm.SensorFault):  # noise tables are sensor models (NoiseSpec)
            raise TypeError(f"noise model {label} is a {type(model).__name__}, not a sensor fault")
        noise.append(model)
    built = [
        build_fault(spec, label, sensors, actuators)
        for spec, label in zip(scenario.faults, fault_labels)
        if not isinstance(spec, OnBus)  # the runner's (cosim.run.busfaults)
    ]
    sensor_faults = [f for f in built if isinstance(f, fm.SensorFault)]
    actuator_faults = [f for f in built if isinstance(f, fm.ActuatorFault)]
    return fm.FaultInjector(noise, sensor_faults, actuator_faults, scenario.seed)


def build_bus_faults(scenario: Any) -> list[fm.BusFault]:
    """The scenario's bus faults, which the runner applies to frames (``cosim.run.busfaults``)."""
    _, labels = scenario.fault_labels()
    built = [
        build_fault(spec, label, (), ()) for spec, label in zip(scenario.faults, labels) if isinstance(spec, OnBus)
    ]
    return [model for model in built if isinstance(model, fm.BusFault)]


def _check_params(kind: str, model: type, params: dict[str, Any]) -> None:
    """A plugin's fault takes as ``params`` only the fields of its dataclass the scenario does not set."""
    known = {f.name for f in dataclass_fields(model) if f.init} - {"channels", "start", "end", "label"}
    if unknown := sorted(set(params) - known):
        raise ValueError(
            f"params: {', '.join(unknown)} is not a parameter of fault {kind!r} "
            f"(it has: {', '.join(sorted(known)) or 'none'})"
        )
