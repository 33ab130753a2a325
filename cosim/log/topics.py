"""The run log's topics, each spelled once: its name, its JSON Schema, how a message is written and read.

A topic is a record class: a dataclass whose fields are the message's JSON fields in the order they
are written, each with its JSON Schema (``tick`` is the runner's tick counter k, ``t`` simulated
time t_k = k τ in s; ``log_time`` is simulated time in ns):

- ``CanFrame``, ``/can/frames``: every frame on the bus in bus order: ``seq`` (position on the
  bus), ``id``, ``extended``, ``fd``, ``brs``, ``dlc`` (the data length code), ``length`` (payload
  bytes), ``data`` (hex), ``sender`` (the DBC node that transmits this id, ``unknown`` for ids
  outside the DBC), ``message`` (DBC name); an imported log's frames add their ``channel``
  (``cosim.log.can_import.ImportedFrame``).
- ``Signals``, ``/can/<MessageName>``: the decoded physical signals of each DBC message, named as
  in the DBC (the integer fields of NMT, SYNC and heartbeats).
- ``TruthState``, ``/truth/state``: the simulator's state, one field per state component;
  ``TruthSensors``, ``/truth/sensors``: the true (fault-free, noise-free) sensor readings.
- ``TruthInputs``, ``/truth/inputs``: ``commanded`` and ``effective`` (after actuator faults)
  inputs per actuator, and the ``disturbance`` per unknown input.
- ``TruthFaults``, ``/truth/faults``: what the fault layer applied: ``noise`` and ``fault``
  (additive parts, per sensor), ``measured`` (what went on the bus; null where the frame was not
  sent), ``dropped`` (sensors whose frame was not sent), ``effectiveness`` (δ per actuator) and
  ``active`` (labels of the active faults).
- ``BusFaultEvent``, ``/truth/bus_faults``: with bus faults only, what each did to a frame.
- ``Event``, ``/cosim/events``: runner events (start, stop, warnings, errors).
- ``DeadlineMiss``, ``/cosim/deadline_misses``: in realtime mode, each tick a node did not answer
  by its deadline.
- ``Foreign``, ``/cosim/foreign``: what arrived on the run's bus and does not belong to it; a
  simulated intruder's frame (a bus fault's) has a record each, with its fault's label
  (``source``) and its ``seq`` on ``/can/frames``: the per-frame labels of a data set.
- ``WirePassage``, ``/cosim/wire``: with ``[bus] timing = "arbitrated"`` only, each frame's
  passage on the simulated wire, logged at its delivery.
- ``SecurityRejection``, ``/cosim/security``: frames a receiver dropped in SecOC verification.
- ``IntrusionVerdict``, ``/cosim/ids``: the key-less intrusion detector's verdict on each tick.

Writing: a record is its own message (``log.write(channel, t_ns, Event(...))``: orjson writes a
dataclass's fields in order). On the per-frame and per-tick path a record's ``payload(...)``
builds the same fields as a dict literal instead, for a third of the cost of building the record
(``tests/test_topics.py`` holds each payload to its record's fields). Reading: ``Record.read``
turns a logged message back into its record; a field the message lacks takes its default (a
required one raises TypeError, which readers of damaged logs catch), and fields it has beyond the
record's are ignored. The truth and decoded topics, whose fields are the run's signal names, have
``schema(...)`` and ``read`` of their own.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import MISSING, dataclass, field, fields
from typing import Any, ClassVar, Self, TypeVar, dataclass_transform

import can
import numpy as np
from can.util import len2dlc

from cosim.bus.codec import CLASSIC_TICK_BITS, CLIENT, COMMAND, ESTIMATE, NMT, SENSOR, Decoded, MessageSpec
from cosim.bus.secoc import REASONS
from cosim.log.writer import number, object_schema

#: python-can's ``len2dlc`` by payload length (every length above 48 bytes codes 15): a look-up per frame.
_DLC = tuple(len2dlc(length) for length in range(65))

# -- schemas of fields ----------------------------------------------------------------------------

TICK: dict[str, Any] = {"type": "integer", "description": "tick counter k of the runner"}
TIME = number("simulated time t_k = k τ", "s")


def integer(description: str = "", nullable: bool = False) -> dict[str, Any]:
    return _typed("integer", description, nullable)


def text(description: str = "", nullable: bool = False, enum: list[str] | None = None) -> dict[str, Any]:
    return _typed("string", description, nullable, enum)


def boolean(description: str) -> dict[str, Any]:
    return _typed("boolean", description)


def array(items: str, description: str) -> dict[str, Any]:
    return {"type": "array", "items": {"type": items}, "description": description}


def _typed(kind: str, description: str, nullable: bool = False, enum: list[str] | None = None) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": [kind, "null"] if nullable else kind}
    if enum:
        schema["enum"] = enum
    if description:
        schema["description"] = description
    return schema


def per_name(names: tuple[str, ...], units: dict[str, str], description: str, nullable: bool = False) -> dict[str, Any]:
    """Schema of an object with one number per name (a sensor, an actuator), each in its unit."""
    return {
        "type": "object",
        "description": description,
        "properties": {n: number(n, units.get(n, ""), nullable) for n in names},
    }


def by_name(names: tuple[str, ...], values: np.ndarray | None) -> dict[str, Any]:
    """Values by their names (none for None); NaN becomes null where the message is written."""
    return dict(zip(names, [] if values is None else values.tolist()))


def prop(schema: dict[str, Any] | None = None, default: Any = MISSING, factory: Any = MISSING) -> Any:
    """A record's field with its JSON Schema (None: the topic's ``schema`` builds it from the run's
    names); ``default``/``factory``: what a logged message without it reads as."""
    return field(default=default, default_factory=factory, metadata={"schema": schema})


# -- records --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PlantNames:
    """The run's signal names and their units (group → name → unit, the groups ``states``,
    ``sensors``, ``actuators`` and ``disturbances``): the truth topics' fields."""

    states: tuple[str, ...]
    sensors: tuple[str, ...]
    actuators: tuple[str, ...]
    disturbances: tuple[str, ...] = ()
    units: dict[str, dict[str, str]] = field(default_factory=dict)

    def unit(self, group: str) -> dict[str, str]:
        return self.units.get(group, {})


class Record:
    """A topic's message as a dataclass: its fields are the message's, in order."""

    __slots__ = ()
    TOPIC: ClassVar[str]
    TITLE: ClassVar[str]
    DESCRIPTION: ClassVar[str]

    @classmethod
    def read(cls, message: dict[str, Any]) -> Self:
        """The record of a logged message (lenient: see the module's docstring)."""
        try:
            return cls(**message)
        except TypeError:  # fields beyond the record's, or some missing
            return cls(**{name: message[name] for name in field_names(cls) if name in message})

    @classmethod
    def schema(cls, plant: PlantNames | None = None) -> dict[str, Any]:
        """The topic's JSON Schema; ``plant``: the run's names, for the topics whose fields they are."""
        return object_schema(cls.TITLE, cls._properties(plant), cls.DESCRIPTION)

    @classmethod
    def _properties(cls, plant: PlantNames | None) -> dict[str, Any]:
        """Each field's JSON Schema; those of fields whose properties are the run's names, ``_named``'s."""
        properties = _fixed(cls)
        if any(schema is None for schema in properties.values()):
            properties |= cls._named(_plant(cls, plant))
        return properties

    @classmethod
    def _named(cls, plant: PlantNames) -> dict[str, Any]:
        """The schemas of the fields that hold a value per name of the run (a sensor, an actuator)."""
        return {}


def _fixed(record: type[Record]) -> dict[str, Any]:
    """Each field's JSON Schema as the record declares it (None where the run's names make it)."""
    return {f.name: f.metadata["schema"] for f in fields(record)}  # type: ignore[arg-type]


R = TypeVar("R", bound=Record)


@dataclass_transform(kw_only_default=True, field_specifiers=(prop,))
def topic(name: str, title: str, description: str) -> Callable[[type[R]], type[R]]:
    """Make a record class the record of topic ``name``: a slotted dataclass whose fields are the
    message's (keyword-only: a field without a default can follow one with), its JSON Schema titled
    ``title`` and described by ``description``."""

    def make(record: type[R]) -> type[R]:
        made = dataclass(slots=True, kw_only=True)(record)
        made.TOPIC, made.TITLE, made.DESCRIPTION = name, title, description
        return made

    return make


@dataclass(slots=True, kw_only=True)
class TickRecord(Record):
    """A record of one tick: the runner's tick counter k and simulated time t_k, then its own fields."""

    tick: int = prop(TICK)
    t: float = prop(TIME)


def _plant(record: type[Record], plant: PlantNames | None) -> PlantNames:
    if plant is None:
        raise TypeError(f"the schema of {record.TOPIC} needs the run's names (PlantNames)")
    return plant


def field_names(record: type) -> tuple[str, ...]:
    return tuple(f.name for f in fields(record))


def path(record: type[Record], name: str, *keys: str) -> str:
    """A field's message path (``/truth/faults.fault.x1``), as Foxglove panels address it; a name
    that is not a field of the record raises."""
    if name not in field_names(record):
        raise KeyError(f"{record.TOPIC} has no field {name!r}")
    return ".".join((record.TOPIC, name, *keys))


@topic("/can/frames", "cosim.CanFrame", "A frame on the run's CAN bus")
class CanFrame(TickRecord):
    seq: int = prop(integer("position of the frame on the bus in this run"))
    id: int = prop(integer("arbitration id"))
    extended: bool = prop(boolean("29-bit identifier"))
    fd: bool = prop(boolean("CAN FD frame"))
    brs: bool = prop(boolean("CAN FD bit rate switch"))
    dlc: int = prop(integer("data length code (0-8; 9-15 code 12-64 bytes in CAN FD)"))
    length: int = prop(integer("payload length in bytes"))
    data: str = prop(text("payload, hex"))
    sender: str = prop(text("transmitting node (from the DBC)"))
    message: str | None = prop(text("DBC message name", nullable=True), default=None)

    @staticmethod
    def payload(tick: int, t: float, seq: int, frame: can.Message, sender: str, message: str | None) -> dict[str, Any]:
        data = frame.data
        return {
            "tick": tick,
            "t": t,
            "seq": seq,
            "id": frame.arbitration_id,
            "extended": frame.is_extended_id,
            "fd": frame.is_fd,
            "brs": frame.bitrate_switch,
            "dlc": _DLC[min(len(data), 64)],
            "length": len(data),
            "data": data.hex(),
            "sender": sender,
            "message": message,
        }

    @classmethod
    def of(cls, tick: int, t: float, seq: int, frame: can.Message, sender: str, message: str | None) -> CanFrame:
        """The record of ``payload``'s message (what reading it back gives), built directly."""
        data = frame.data
        return cls(
            tick=tick,
            t=t,
            seq=seq,
            id=frame.arbitration_id,
            extended=frame.is_extended_id,
            fd=frame.is_fd,
            brs=frame.bitrate_switch,
            dlc=_DLC[min(len(data), 64)],
            length=len(data),
            data=data.hex(),
            sender=sender,
            message=message,
        )

    @property
    def payload_bytes(self) -> bytes:
        return bytes.fromhex(self.data)

    def can_message(self, timestamp: float = 0.0) -> can.Message:
        """The python-can message this record describes."""
        return can.Message(
            timestamp=timestamp,
            arbitration_id=self.id,
            is_extended_id=self.extended,
            is_fd=self.fd,
            bitrate_switch=self.brs,
            data=self.payload_bytes,
        )


@dataclass(slots=True)
class Signals:
    """``/can/<MessageName>``: a DBC message's decoded signals, by their DBC names; read back with
    ``tick``, the tick the frame belongs to (its counter unwrapped, ``carried_tick``)."""

    tick: int
    values: dict[str, Any]

    @staticmethod
    def topic(message: str) -> str:
        return f"/can/{message}"

    @classmethod
    def schema(cls, spec: MessageSpec) -> dict[str, Any]:
        if spec.channels or spec.role in (ESTIMATE, CLIENT, SENSOR, COMMAND):
            properties = {"tick": integer("tick counter signal as carried by the frame")}
            for channel, signal in zip(spec.channels, spec.signals):
                properties[signal] = number(channel.description, channel.unit)
        else:  # NMT, SYNC and heartbeats: integer fields
            properties = {name: {"type": "integer"} for name in spec.signals}
        return object_schema(f"cosim.{spec.name}", properties, f"Decoded signals of {spec.name}")

    @staticmethod
    def payload(decoded: Decoded) -> dict[str, Any]:
        return decoded.values if decoded.spec.role == NMT else {"tick": decoded.tick, **decoded.values}

    @classmethod
    def read(cls, message: dict[str, Any], logged_tick: int) -> Signals:
        """The signals of a message logged at tick ``logged_tick`` (its log time over the sample time)."""
        tick = carried_tick(logged_tick, message["tick"])
        return cls(tick, {name: value for name, value in message.items() if name != "tick"})


def message_topic(name: str) -> str:
    """The topic of a DBC message's decoded signals."""
    return Signals.topic(name)


def decoded_topics(messages: dict[str, list[str]]) -> dict[str, str]:
    """The topics that carry each participant's messages (participant → its DBC messages), each
    mapped to its participant."""
    return {message_topic(m): name for name, names in messages.items() for m in names}


def carried_tick(logged_tick: int, counter: int) -> int:
    """The tick a decoded frame belongs to: its counter (k mod 2¹⁶ in classic CAN, k in CAN FD)
    unwrapped against the tick at which it was logged, which is never earlier (a late frame, in
    realtime mode, is logged at a later tick; fewer than 2¹⁶ ticks late is assumed)."""
    return logged_tick - (logged_tick - int(counter)) % (1 << CLASSIC_TICK_BITS)


@topic("/truth/state", "cosim.TruthState", "State of the simulated plant")
class TruthState(TickRecord):
    """One field per state component (``values`` when read)."""

    GROUP: ClassVar[str] = "states"

    values: dict[str, float] = prop(factory=dict)

    @classmethod
    def _properties(cls, plant: PlantNames | None) -> dict[str, Any]:
        plant = _plant(cls, plant)
        units = plant.unit(cls.GROUP)
        return {"tick": TICK, "t": TIME, **{n: number(n, units.get(n, "")) for n in getattr(plant, cls.GROUP)}}

    @staticmethod
    def payload(tick: int, t: float, names: tuple[str, ...], values: np.ndarray) -> dict[str, Any]:
        return {"tick": tick, "t": t, **by_name(names, values)}

    @classmethod
    def read(cls, message: dict[str, Any]) -> Self:
        values = {name: value for name, value in message.items() if name not in ("tick", "t")}
        return cls(tick=message["tick"], t=message["t"], values=values)

    def vector(self, names: list[str] | tuple[str, ...]) -> np.ndarray:
        return np.array([self.values[name] for name in names])


@topic("/truth/sensors", "cosim.TruthSensors", "True (fault-free, noise-free) sensor readings")
class TruthSensors(TruthState):
    """One field per sensor (``values`` when read)."""

    GROUP = "sensors"


@topic("/truth/inputs", "cosim.TruthInputs", "Actuator inputs and unknown inputs")
class TruthInputs(TickRecord):
    commanded: dict[str, float] = prop(factory=dict)
    effective: dict[str, float] = prop(factory=dict)
    disturbance: dict[str, float] = prop(factory=dict)

    @classmethod
    def _named(cls, plant: PlantNames) -> dict[str, Any]:
        actuators, units = plant.actuators, plant.unit("actuators")
        return {
            "commanded": per_name(actuators, units, "commanded input per actuator"),
            "effective": per_name(actuators, units, "input acting on the plant after actuator faults"),
            "disturbance": per_name(
                plant.disturbances, plant.unit("disturbances"), "unknown input acting on the plant (not on the bus)"
            ),
        }

    @staticmethod
    def payload(
        tick: int,
        t: float,
        plant: PlantNames,
        commanded: np.ndarray,
        effective: np.ndarray,
        disturbance: np.ndarray | None,
    ) -> dict[str, Any]:
        return {
            "tick": tick,
            "t": t,
            "commanded": by_name(plant.actuators, commanded),
            "effective": by_name(plant.actuators, effective),
            "disturbance": by_name(plant.disturbances, disturbance),
        }


@topic("/truth/faults", "cosim.TruthFaults", "Faults and noise applied by the fault layer")
class TruthFaults(TickRecord):
    noise: dict[str, float] = prop(factory=dict)
    fault: dict[str, float | None] = prop(factory=dict)
    measured: dict[str, float | None] = prop(factory=dict)
    dropped: list[str] = prop(array("string", "sensors whose frame was not sent"), factory=list)
    effectiveness: dict[str, float] = prop(factory=dict)
    active: list[str] = prop(array("string", "labels of the active faults"))

    @classmethod
    def _named(cls, plant: PlantNames) -> dict[str, Any]:
        sensors, units = plant.sensors, plant.unit("sensors")
        return {
            "noise": per_name(sensors, units, "measurement noise added per sensor"),
            "fault": per_name(sensors, units, "deviation added by faults per sensor", nullable=True),
            "measured": per_name(sensors, units, "reading sent on the bus (null: not sent)", nullable=True),
            "effectiveness": per_name(plant.actuators, {}, "actuator effectiveness factor δ"),
        }

    @staticmethod
    def payload(
        tick: int,
        t: float,
        plant: PlantNames,
        noise: np.ndarray,
        fault: np.ndarray,
        measured: np.ndarray,
        delta: np.ndarray,
        active: tuple[str, ...],
    ) -> dict[str, Any]:
        sensors = plant.sensors
        return {
            "tick": tick,
            "t": t,
            "noise": by_name(sensors, noise),
            "fault": by_name(sensors, fault),
            "measured": by_name(sensors, measured),
            "dropped": [name for name, value in zip(sensors, measured) if value != value],
            "effectiveness": by_name(plant.actuators, delta),
            "active": list(active),
        }


@topic("/cosim/deadline_misses", "cosim.DeadlineMiss", "Realtime mode: ticks a node did not answer in time")
class DeadlineMiss(TickRecord):
    node: str = prop(text("the node whose heartbeat for this tick was not in by its deadline"))
    count: int = prop(integer("deadline misses so far in the run"))


@topic(
    "/cosim/foreign", "cosim.Foreign", "What arrived on the run's bus and does not belong to it: counted, never used"
)
class Foreign(TickRecord):
    kind: str = prop(
        text("a datagram that is no frame of the run, or a frame the run did not send", enum=["datagram", "frame"])
    )
    reason: str = prop(text("why it does not belong"))
    source: str = prop(text("where it came from, where known (an intruder's frame: the label of its fault)"))
    id: int | None = prop(integer("arbitration id (frames)", nullable=True), default=None)
    length: int = prop(integer("bytes received (datagram) or payload bytes (frame)"))
    data: str = prop(text("the first bytes, hex"))
    count: int = prop(integer("how many such arrived in this tick that this record stands for"), default=1)
    seq: int | None = prop(
        integer("the frame's seq on /can/frames (an intruder's frame: the one this record labels)", nullable=True),
        default=None,
    )


@topic("/cosim/events", "cosim.Event", "Runner events")
class Event(TickRecord):
    level: str = prop(text(enum=["info", "warning", "error"]), default="info")
    event: str = prop(text(), default="")
    detail: str = prop(text(), default="")
    count: int = prop(integer("how many (frames lost, deadlines missed, ...)"), default=1)


@topic("/truth/bus_faults", "cosim.BusFaultEvent", "What a bus fault did to a frame")
class BusFaultEvent(TickRecord):
    """What a bus fault did (the fields of ``cosim.run.busfaults.BusEvent``)."""

    label: str = prop(text("the fault's label"))
    kind: str = prop(text("the fault's kind"))
    message: str = prop(text("the message (or node) it hit"))
    event: str = prop(text(enum=["lost", "delayed", "corrupted", "bus_off", "recovered", "injected"]))
    errors: int = prop(integer("error frames (corrupted), TEC (bus_off)"), default=0)
    delay: float = prop(number("how long the frame was held back", "s"), default=0.0)


@topic("/cosim/wire", "cosim.WirePassage", "A frame's passage on the simulated wire (arbitrated timing)")
class WirePassage(TickRecord):
    id: int = prop(integer("arbitration id"))
    message: str | None = prop(text("DBC message name", nullable=True))
    sender: str = prop(text("the node that queued it"))
    queued: float = prop(number("when its sender queued it", "s"))
    start: float = prop(number("its start of frame on the wire", "s"))
    delivered: float = prop(number("when its last bit was on the wire", "s"))
    latency: float = prop(number("delivered − queued", "s"))
    late: bool = prop(boolean("delivered after its deadline"))
    bits: int = prop(integer("its length on the wire, stuff bits included"))
    dropped: str | None = prop(text("why it never went out", nullable=True), default=None)

    @staticmethod
    def payload(
        tick: int,
        t_ns: int,
        frame_id: int,
        message: str | None,
        sender: str,
        queued_ns: int,
        start_ns: int,
        delivered_ns: int,
        late: bool,
        bits: int,
        dropped: str | None,
    ) -> dict[str, Any]:
        """A passage logged at ``t_ns``, its delivery."""
        return {
            "tick": tick,
            "t": t_ns / 1e9,
            "id": frame_id,
            "message": message,
            "sender": sender,
            "queued": queued_ns / 1e9,
            "start": start_ns / 1e9,
            "delivered": delivered_ns / 1e9,
            "latency": (delivered_ns - queued_ns) / 1e9,
            "late": late,
            "bits": bits,
            "dropped": dropped,
        }


@topic("/cosim/security", "cosim.SecurityRejection", "A frame dropped by SecOC verification")
class SecurityRejection(TickRecord):
    id: int = prop(integer("arbitration id"))
    message: str | None = prop(text("DBC message name", nullable=True))
    sender: str = prop(text("the sender it claims to come from (the id's owner)"))
    reason: str = prop(
        text(
            "bad_mac: the MAC does not match; replayed: freshness not newer than the "
            "last accepted; stale: older than the acceptance window",
            enum=list(REASONS),
        )
    )
    freshness: int = prop(integer("the full freshness value as rebuilt"))
    data: str = prop(text("its payload (hex): a replay skips this frame"), default="")


#: The key-less intrusion detector's checks (``cosim.run.detector``), as its verdicts name them.
IDS_CHECKS = ("period", "sequence", "range", "unknown")


def _check(name: str) -> Any:
    """A field of the intrusion detector's verdict: how many ids check ``name`` raised on."""
    return prop(integer(f"ids the {name} check raised on"))


@topic(
    "/cosim/ids",
    "cosim.IntrusionVerdict",
    "The key-less intrusion detector's verdict on a tick: period, sequence, range, unknown sender",
)
class IntrusionVerdict(TickRecord):
    alarm: bool = prop(boolean("any check raised in this tick"))
    period: int = _check("period")
    sequence: int = _check("sequence")
    range: int = _check("range")
    unknown: int = _check("unknown")
    ids: list[int] = prop(array("integer", "those ids"))

    @staticmethod
    def payload(tick: int, t: float, checks: dict[str, int], ids: list[int]) -> dict[str, Any]:
        """``checks``: how many ids each of ``IDS_CHECKS`` raised on."""
        return {"tick": tick, "t": t, "alarm": any(checks.values()), **checks, "ids": ids}

    def checks(self) -> dict[str, int]:
        return {check: getattr(self, check) for check in IDS_CHECKS}


@topic(
    "/plant/fmu", "cosim.FmuMessage", "What an FMU plant logged (its logger callback) or printed (its stdout, stderr)"
)
class FmuMessage(TickRecord):
    source: str = prop(text("where it came from", enum=["logger", "stdout", "stderr"]))
    status: str = prop(
        text("the FMI status the FMU logged it with (OK, Warning, Discard, Error, Fatal); empty for a printed line")
    )
    category: str = prop(text("the FMU's log category (logger); empty for a printed line"))
    message: str = prop(text("the message, or one printed line"))


# -- the topics' names, for readers that choose topics ---------------------------------------------

FRAMES = CanFrame.TOPIC
STATE, SENSORS, INPUTS, FAULTS = TruthState.TOPIC, TruthSensors.TOPIC, TruthInputs.TOPIC, TruthFaults.TOPIC
#: The truth of each tick, in the order it is written.
TRUTH = (STATE, SENSORS, INPUTS, FAULTS)
BUS_FAULTS = BusFaultEvent.TOPIC
EVENTS, DEADLINE_MISSES, FOREIGN = Event.TOPIC, DeadlineMiss.TOPIC, Foreign.TOPIC
WIRE, SECURITY, IDS = WirePassage.TOPIC, SecurityRejection.TOPIC, IntrusionVerdict.TOPIC
FMU_MESSAGES = FmuMessage.TOPIC
