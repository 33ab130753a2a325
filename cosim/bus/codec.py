"""The run's CAN database (DBC), generated with cantools, and the encoding of values into frames.

Frame layout (CANopen-flavoured; ids in hex)
---------------------------------------------
- ``NMT`` (0x000, sent by ``runner``): network management, ``command`` (1 start, 2 stop) and
  ``node`` (0: all nodes). The runner sends "stop all" when a run ends.
- ``SYNC`` (0x080, CANopen's default SYNC COB-ID, sent by ``runner``): ``tick`` (uint32), the
  tick counter k, and ``frames`` (uint8), how many data frames the runner sends for tick k right
  after it (sensor and command frames). A receiver knows it has all of tick k's inputs when it has
  that many; a frame not sent by an injected dropout is simply not counted.
- ``SENSOR_<name>`` (0x100 + i, sent by ``plant``): one frame per sensor, like a smart sensor on
  its own node: ``tick`` and the reading.
- ``COMMAND_<name>`` (0x180 + i, sent by ``controller``): the commanded input of each actuator:
  the runner's open-loop input signals, or, in a closed-loop run, the ``controller`` node's.
- ``CONTROL_STATUS[_n]`` (0x1C0 + n, sent by a ``controller`` node): its diagnostics.
- ``EST_<estimator>[_n]`` (0x200 + 0x20·e + n, sent by the estimator): its estimate x̂_k
  (``xhat_<state>``) and its diagnostics (named as the estimator declares them, e.g. ``s_x1``,
  ``phihat_x2``, ``h``), packed into as few frames as fit.
- ``CLIENT_<client>[_n]`` (0x600 + 0x10·c + n, sent by a client declared in the scenario): the
  client's own signals.
- ``HEARTBEAT_<node>`` (0x700 + node id, sent by each estimator or client node): ``state``
  (CANopen NMT state: 0 boot-up, 4 stopped, 5 operational), ``tick``, ``frames`` (data frames the
  node sent for that tick) and ``lost`` (frames the node found missing so far). A node sends its
  boot-up heartbeat when it joins and one operational heartbeat after its frames of every tick:
  that is what the runner waits for in lockstep, and what per-sender loss counting rests on.

Every data frame carries ``tick``: k mod 2¹⁶ in classic CAN (16 bits), k in CAN FD (32 bits).
Classic CAN signals are scaled signed integers whose resolution and range come from the plant
module (or the scenario's overrides); CAN FD signals are float64. NMT, SYNC and heartbeats are
classic frames on either bus. A value outside its declared range, or not finite, is a CodecError
naming the signal: never silently wrapped or clipped.

The DBC text is complete: ``Codec.from_dbc`` rebuilds the same codec from it, which is how node
processes and clients get theirs.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING

import can
import cantools
from cantools.database.can import Bus, Database, Message, Node, Signal
from cantools.database.can.formats.dbc.dbc_attribute import DbcAttribute
from cantools.database.can.formats.dbc.dbc_attribute_definition import DbcAttributeDefinition
from cantools.database.can.formats.dbc.dbc_specifics import DbcSpecifics
from cantools.database.conversion import BaseConversion

from cosim.bus.packing import Packer
from cosim.bus.secoc import strip as strip_secoc
from cosim.bus.signals import Channel
from cosim.errors import CodecError

if TYPE_CHECKING:
    from cantools.database.can.formats.dbc.dbc_attribute import DbcAttributeType
    from cantools.database.can.formats.dbc.dbc_attribute_definition import DbcAttributeDefinitionType

NMT_ID = 0x000
SYNC_ID = 0x080
SENSOR_BASE = 0x100
COMMAND_BASE = 0x180
CONTROL_BASE = 0x1C0
ESTIMATE_BASE = 0x200
ESTIMATE_STRIDE = 0x20
CLIENT_BASE = 0x600
CLIENT_STRIDE = 0x10
HEARTBEAT_BASE = 0x700
MAX_NODE_ID = 0x7F

CLASSIC_TICK_BITS = 16
FD_TICK_BITS = 32
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


class Role(StrEnum):
    """What a message is for: its id block, its name and who may send it follow from its role."""

    NMT = "nmt"
    SYNC = "sync"
    HEARTBEAT = "heartbeat"
    SENSOR = "sensor"
    COMMAND = "command"
    CONTROL = "control"
    ESTIMATE = "estimate"
    CLIENT = "client"


NMT, SYNC, HEARTBEAT = Role.NMT, Role.SYNC, Role.HEARTBEAT
SENSOR, COMMAND, CONTROL, ESTIMATE, CLIENT = Role.SENSOR, Role.COMMAND, Role.CONTROL, Role.ESTIMATE, Role.CLIENT
#: The DBC nodes of the runner's own frames, of the sensors and of the controller node (or the
#: runner's open-loop inputs); estimators and clients are nodes named as in the scenario.
RUNNER, PLANT, CONTROLLER = "runner", "plant", "controller"

NMT_START, NMT_STOP = 0x01, 0x02  # CANopen NMT command specifiers
BOOTUP, STOPPED, OPERATIONAL = 0x00, 0x04, 0x05  # CANopen NMT states, as heartbeats carry them

#: The scenario table that overrides a channel's range, per message role.
OVERRIDE_TABLE = {
    SENSOR: "bus.sensors",
    COMMAND: "bus.actuators",
    CONTROL: "bus.states",
    ESTIMATE: "bus.states",
    CLIENT: "clients",
}
#: Identifier blocks: [first, end) per role.
ID_BLOCKS = {
    SENSOR: (SENSOR_BASE, COMMAND_BASE),
    COMMAND: (COMMAND_BASE, ESTIMATE_BASE),
    ESTIMATE: (ESTIMATE_BASE, CLIENT_BASE),
    CLIENT: (CLIENT_BASE, HEARTBEAT_BASE),
}
#: Signal prefix per role (estimates are named after the state they estimate).
SIGNAL_PREFIX = {ESTIMATE: "xhat_"}
#: Message name prefix per role; a node's data messages are numbered (``EST_kalman_0``, ...) when
#: they need more than one frame per tick.
MESSAGE_PREFIX = {
    SENSOR: "SENSOR",
    COMMAND: "COMMAND",
    CONTROL: "CONTROL_STATUS",
    ESTIMATE: "EST",
    CLIENT: "CLIENT",
    HEARTBEAT: "HEARTBEAT",
}


def sensor_message(sensor: str) -> str:
    """The name of the message that carries a sensor's reading."""
    return f"{MESSAGE_PREFIX[SENSOR]}_{sensor}"


def command_message(actuator: str) -> str:
    """The name of the message that carries an actuator's command."""
    return f"{MESSAGE_PREFIX[COMMAND]}_{actuator}"


def heartbeat_message(node: str) -> str:
    """The name of a node's heartbeat message."""
    return f"{MESSAGE_PREFIX[HEARTBEAT]}_{node}"


def estimate_signal(state: str) -> str:
    """The signal that carries an estimator's estimate of a state component."""
    return SIGNAL_PREFIX[ESTIMATE] + state


def estimated_state(signal: str) -> str | None:
    """The state component an estimate signal carries; None for a diagnostic signal."""
    prefix = SIGNAL_PREFIX[ESTIMATE]
    return signal[len(prefix) :] if signal.startswith(prefix) else None


@dataclass(frozen=True)
class MessageSpec:
    """One DBC message: its name, id, sending node, role, and the channels its signals carry."""

    name: str
    frame_id: int
    sender: str
    role: Role
    channels: tuple[Channel, ...]
    signals: tuple[str, ...]


@dataclass(frozen=True)
class Decoded:
    """A decoded frame: its message, the tick counter it carries, and its physical values."""

    spec: MessageSpec
    tick: int
    values: dict[str, float]


def signal_bits(channel: Channel) -> int:
    """Bits of a signed integer signal that spans the channel's range at its resolution."""
    span = max(abs(channel.minimum), abs(channel.maximum)) / channel.resolution
    return math.ceil(math.log2(span + 1.0)) + 1


def _fd_length(nbytes: int) -> int:
    for length in FD_LENGTHS:
        if length >= nbytes:
            return length
    raise CodecError(f"{nbytes} bytes do not fit a CAN FD frame (at most 64)")


def pack_channels(
    prefix: str,
    base_id: int,
    sender: str,
    role: Role,
    channels: Sequence[Channel],
    fd: bool,
    signals: Sequence[str] | None = None,
) -> list[MessageSpec]:
    """Lay channels out in as few frames as fit, in order: 8-byte classic frames of scaled integers
    after a 16-bit tick, or 64-byte FD frames of float64 after a 32-bit tick. Signals are named
    after their channels (with the role's prefix) unless ``signals`` names them."""
    capacity = 64 * 8 - FD_TICK_BITS if fd else 64 - CLASSIC_TICK_BITS
    if signals is None:
        signals = [SIGNAL_PREFIX.get(role, "") + c.name for c in channels]
    groups: list[list[tuple[Channel, str]]] = [[]]
    used = 0
    for channel, signal in zip(channels, signals):
        bits = 64 if fd else signal_bits(channel)
        if bits > capacity:
            raise CodecError(
                f"signal {signal} needs {bits} bits at resolution {channel.resolution:g} "
                f"{channel.unit} over [{channel.minimum:g}, {channel.maximum:g}], and at most {capacity} fit a classic "
                f"frame: set a coarser resolution or a narrower range with [{OVERRIDE_TABLE[role]}.{channel.name}], "
                f"or use CAN FD (bus.fd = true)"
            )
        if used + bits > capacity:
            groups.append([])
            used = 0
        groups[-1].append((channel, signal))
        used += bits
    return [
        MessageSpec(
            prefix if len(groups) == 1 else f"{prefix}_{n}",
            base_id + n,
            sender,
            role,
            tuple(c for c, _ in group),
            tuple(name for _, name in group),
        )
        for n, group in enumerate(groups)
    ]


class Codec:
    """The CAN database of one run, and fast, range-checked encoding and decoding of its frames.

    Built from the transmitted sensors, the actuators, each estimator's output channels and each
    declared client's signals; ``fd`` selects CAN FD (float64 signals) or classic CAN (scaled
    integers). Estimators get node ids 1, 2, … in order, then the clients, then the controller:
    with ``controller`` (its diagnostic channels, possibly none) the commands come from a
    ``controller`` node, which has a heartbeat and a CONTROL_STATUS message.
    """

    secoc_trailers: Mapping[int, int] = {}
    """Secured ids (``cosim.bus.secoc``) and the byte where their trailer starts; empty: no SecOC."""
    _secured_dbc: str | None = None

    def __init__(
        self,
        sensors: Sequence[Channel],
        actuators: Sequence[Channel],
        estimators: Mapping[str, Sequence[Channel]],
        *,
        diagnostics: Mapping[str, Sequence[Channel]] | None = None,
        clients: Mapping[str, Sequence[Channel]] | None = None,
        controller: Sequence[Channel] | None = None,
        fd: bool = False,
        bitrate: int = 500_000,
        data_bitrate: int = 2_000_000,
        cycle_time: float | None = None,
    ) -> None:
        clients = dict(clients or {})
        counts = {
            SENSOR: len(sensors),
            COMMAND: len(actuators),
            ESTIMATE: len(estimators) * ESTIMATE_STRIDE,
            CLIENT: len(clients) * CLIENT_STRIDE,
        }
        for role, count in counts.items():
            first, end = ID_BLOCKS[role]
            if count > end - first:
                stride = {ESTIMATE: ESTIMATE_STRIDE, CLIENT: CLIENT_STRIDE}.get(role, 1)
                what = {SENSOR: "sensors", COMMAND: "actuators", ESTIMATE: "estimators", CLIENT: "clients"}[role]
                raise CodecError(
                    f"too many {what} for the bus: at most {(end - first) // stride} fit ids "
                    f"0x{first:03X}-0x{end - 1:03X}"
                )
        nodes = [*estimators, *clients, *([CONTROLLER] if controller is not None else [])]
        if len(set(nodes)) != len(nodes):
            raise CodecError(f"estimator, client and controller names must differ: {', '.join(nodes)}")
        if controller is not None and len(actuators) > CONTROL_BASE - COMMAND_BASE:
            raise CodecError(
                f"too many actuators for a controller node: at most {CONTROL_BASE - COMMAND_BASE} fit ids "
                f"0x{COMMAND_BASE:03X}-0x{CONTROL_BASE - 1:03X}"
            )
        specs = [
            MessageSpec("NMT", NMT_ID, RUNNER, NMT, (), ("command", "node")),
            MessageSpec("SYNC", SYNC_ID, RUNNER, SYNC, (), ("tick", "frames")),
        ]
        for i, channel in enumerate(sensors):
            specs += pack_channels(sensor_message(channel.name), SENSOR_BASE + i, PLANT, SENSOR, [channel], fd)
        for i, channel in enumerate(actuators):
            specs += pack_channels(command_message(channel.name), COMMAND_BASE + i, CONTROLLER, COMMAND, [channel], fd)
        if controller:
            specs += pack_channels(
                MESSAGE_PREFIX[CONTROL],
                CONTROL_BASE,
                CONTROLLER,
                CONTROL,
                list(controller),
                fd,
                [c.name for c in controller],
            )
        diagnostics = dict(diagnostics or {})
        for group, base, stride, role, prefix in (
            (estimators, ESTIMATE_BASE, ESTIMATE_STRIDE, ESTIMATE, MESSAGE_PREFIX[ESTIMATE]),
            (clients, CLIENT_BASE, CLIENT_STRIDE, CLIENT, MESSAGE_PREFIX[CLIENT]),
        ):
            for e, (name, channels) in enumerate(group.items()):
                extra = list(diagnostics.get(name, ())) if role == ESTIMATE else []
                signals = [SIGNAL_PREFIX.get(role, "") + c.name for c in channels] + [c.name for c in extra]
                packed = pack_channels(
                    f"{prefix}_{name}", base + stride * e, name, role, [*channels, *extra], fd, signals
                )
                if len(packed) > stride:
                    raise CodecError(f"{name} needs {len(packed)} frames per tick; at most {stride} fit its id block")
                specs += packed
        for node_id, name in enumerate(nodes, start=1):
            specs.append(
                MessageSpec(
                    heartbeat_message(name),
                    HEARTBEAT_BASE + node_id,
                    name,
                    HEARTBEAT,
                    (),
                    ("state", "tick", "frames", "lost"),
                )
            )
        cycle_ms = None if cycle_time is None or cycle_time < 1e-3 else int(round(cycle_time * 1000))
        self._setup(_database(specs, fd, bitrate, data_bitrate, cycle_ms), specs, fd)

    @classmethod
    def from_dbc(cls, text: str) -> Codec:
        """The codec described by a DBC written by ``Codec.dbc`` (or ``cosim dbc``)."""
        try:
            database = load_dbc(text)
        except Exception as error:  # cantools raises several parse error types
            raise CodecError(f"the DBC cannot be parsed: {error}") from None
        # The SecOC trailer is no signal of the codec: taken out, the secured frames keep their length.
        trailers = strip_secoc(database)
        fd = any(m.is_fd for m in database.messages) or _bus_type(database) == "CAN FD"
        specs = [_spec_from_message(m) for m in database.messages]
        codec = cls.__new__(cls)
        codec._setup(database, specs, fd)
        if trailers:
            codec.secoc_trailers, codec._secured_dbc = trailers, text
        return codec

    def _setup(self, database: Database, specs: list[MessageSpec], fd: bool) -> None:
        self.fd = fd
        self.database = database
        bus = database.buses[0] if database.buses else None
        self.bitrate = bus.baudrate if bus and bus.baudrate else 500_000
        self.data_bitrate = bus.fd_baudrate if bus and bus.fd_baudrate else 2_000_000
        self.specs: dict[str, MessageSpec] = {spec.name: spec for spec in specs}
        self._by_id: dict[int, MessageSpec] = {spec.frame_id: spec for spec in specs}
        self._messages: dict[str, Message] = {m.name: m for m in database.messages}
        # Each message compiled once into a packer (cosim.bus.packing) from cantools' message: the
        # tick counter first, then the spec's signals, in the order encode takes their values.
        self._packers: dict[str, Packer] = {}
        for spec in specs:
            message = self._messages[spec.name]
            has_tick = any(signal.name == "tick" for signal in message.signals) and "tick" not in spec.signals
            self._packers[spec.name] = Packer(message, ("tick", *spec.signals) if has_tick else spec.signals)
        # id -> (spec, packer, where the tick counter is among the packer's values, the other signals)
        self._unpacking: dict[int, tuple[MessageSpec, Packer, int | None, tuple[str, ...]]] = {}
        for spec in specs:
            names = self._packers[spec.name].names
            at = names.index("tick") if "tick" in names else None
            others = tuple(name for name in names if name != "tick")
            self._unpacking[spec.frame_id] = (spec, self._packers[spec.name], at, others)
        self.tick_modulus = 2**FD_TICK_BITS if fd else 2**CLASSIC_TICK_BITS
        self.node_ids: dict[str, int] = {
            spec.sender: spec.frame_id - HEARTBEAT_BASE for spec in specs if spec.role == HEARTBEAT
        }

    # -- database -------------------------------------------------------------------------------

    @property
    def dbc(self) -> str:
        """The database as DBC text (CAN FD frames are marked with VFrameFormat; a secured one as it was read)."""
        return self._secured_dbc if self._secured_dbc is not None else self.database.as_dbc_string()

    def messages(self, role: str | None = None, sender: str | None = None) -> list[MessageSpec]:
        """Message specs, optionally only those of one role or sender, in id order."""
        return sorted(
            (
                s
                for s in self.specs.values()
                if (role is None or s.role == role) and (sender is None or s.sender == sender)
            ),
            key=lambda s: s.frame_id,
        )

    def sensor(self, name: str) -> MessageSpec:
        """The message of a sensor's reading."""
        return self.specs[sensor_message(name)]

    def command(self, name: str) -> MessageSpec:
        """The message of an actuator's command."""
        return self.specs[command_message(name)]

    def data_messages(self, sender: str) -> list[MessageSpec]:
        """The messages a node sends every tick (its heartbeat excluded)."""
        return [s for s in self.messages(sender=sender) if s.role != HEARTBEAT]

    # -- frames ---------------------------------------------------------------------------------

    def _classic(self, name: str, values: dict[str, int]) -> can.Message:
        spec, packer = self.specs[name], self._packers[name]
        data = packer.encode([values[signal] for signal in packer.names])
        return can.Message(arbitration_id=spec.frame_id, data=data, is_extended_id=False)

    def sync(self, tick: int, frames: int) -> can.Message:
        if not 0 <= frames <= 255:
            raise CodecError(f"tick {tick} has {frames} data frames; a SYNC can announce at most 255")
        return self._classic("SYNC", {"tick": tick % 2**32, "frames": frames})

    def nmt(self, command: int, node: int = 0) -> can.Message:
        return self._classic("NMT", {"command": command, "node": node})

    def heartbeat(self, node: str, state: int, tick: int = 0, frames: int = 0, lost: int = 0) -> can.Message:
        return self._classic(
            heartbeat_message(node),
            {"state": state, "tick": tick % 2**32, "frames": min(frames, 255), "lost": min(lost, 2**16 - 1)},
        )

    def encode(self, name: str, tick: int, values: Sequence[float]) -> can.Message:
        """The frame of message ``name`` for tick k carrying ``values`` (one per signal, in order)."""
        spec = self.specs[name]
        return self._frame(spec, self._packers[name].encode(self._payload(spec, tick, values)))

    def encode_decoded(self, name: str, tick: int, values: Sequence[float]) -> tuple[can.Message, Decoded]:
        """The frame, and what a receiver decodes from it (the values as the frame carries them,
        quantized in classic CAN), without decoding it again."""
        spec = self.specs[name]
        payload = self._payload(spec, tick, values)
        data, carried = self._packers[name].encode_carried(payload)
        return self._frame(spec, data), Decoded(spec, int(payload[0]), dict(zip(spec.signals, carried[1:])))

    def _payload(self, spec: MessageSpec, tick: int, values: Sequence[float]) -> list[float]:
        """The tick counter and the values, each checked against its channel's range."""
        payload: list[float] = [tick % self.tick_modulus]
        for channel, value in zip(spec.channels, values, strict=True):
            if not (channel.minimum <= value <= channel.maximum):  # also rejects NaN
                signal = spec.signals[len(payload) - 1]
                raise CodecError(_range_message(spec, signal, channel, value, tick))
            payload.append(float(value))
        return payload

    def _frame(self, spec: MessageSpec, data: bytes) -> can.Message:
        return can.Message(
            arbitration_id=spec.frame_id, data=data, is_extended_id=False, is_fd=self.fd, bitrate_switch=self.fd
        )

    def spec_of(self, frame: can.Message) -> MessageSpec | None:
        return None if frame.is_extended_id else self._by_id.get(frame.arbitration_id)

    def decode(self, frame: can.Message) -> Decoded | None:
        """The decoded frame, or None for a frame this database does not describe; a CodecError for a
        frame on one of its ids that is not one of its frames (another length)."""
        found = None if frame.is_extended_id else self._unpacking.get(frame.arbitration_id)
        if found is None:
            return None
        spec, packer, at, others = found
        data = frame.data
        if len(data) != packer.length:  # a frame of another length is no frame of this message
            raise CodecError(
                f"frame 0x{frame.arbitration_id:03X} ({spec.name}) has {len(data)} data bytes; the message has "
                f"{packer.length}"
            )
        values = packer.unpack(data)
        if at == 0:  # every data frame, SYNC
            return Decoded(spec, int(values[0]), dict(zip(others, values[1:])))
        if at is None:  # NMT
            return Decoded(spec, 0, dict(zip(others, values)))
        return Decoded(spec, int(values[at]), dict(zip(others, values[:at] + values[at + 1 :])))


def _range_message(spec: MessageSpec, signal: str, channel: Channel, value: float, tick: int) -> str:
    where = f"signal {spec.name}.{signal} at tick {tick}"
    if math.isnan(value):
        return f"{where} is not a number (NaN) and cannot be sent"
    return (
        f"{where} = {value:g} {channel.unit} is outside its declared range "
        f"[{channel.minimum:g}, {channel.maximum:g}] {channel.unit}: widen it in the scenario with "
        f"[{OVERRIDE_TABLE[spec.role]}.{channel.name}] minimum = ... / maximum = ..., "
        f"or find out why the value left it"
    )


# -- the DBC ------------------------------------------------------------------------------------


#: The integer signals of the control messages: (name, start bit, length, comment).
_CONTROL_LAYOUT = {
    NMT: [("command", 0, 8, "NMT command: 1 start, 2 stop"), ("node", 8, 8, "addressed node id, 0 for all")],
    SYNC: [
        ("tick", 0, 32, "tick counter k"),
        ("frames", 32, 8, "data frames the runner sends for tick k after this SYNC"),
    ],
    HEARTBEAT: [
        ("state", 0, 8, "NMT state: 0 boot-up, 4 stopped, 5 operational"),
        ("tick", 8, 32, "the tick this heartbeat closes"),
        ("frames", 40, 8, "data frames the node sent for that tick"),
        ("lost", 48, 16, "frames the node found missing so far"),
    ],
}
_CONTROL_COMMENTS = {NMT: "network management (CANopen NMT)", SYNC: "start of tick k", HEARTBEAT: "node heartbeat"}


def _database(specs: list[MessageSpec], fd: bool, bitrate: int, data_bitrate: int, cycle_ms: int | None) -> Database:
    messages = []
    for spec in specs:
        if spec.role in _CONTROL_LAYOUT:
            signals = [
                Signal(name, start, length, comment=comment)
                for name, start, length, comment in _CONTROL_LAYOUT[spec.role]
            ]
            length = (max(s.start + s.length for s in signals) + 7) // 8
            messages.append(
                Message(
                    spec.frame_id,
                    spec.name,
                    length,
                    signals,
                    senders=[spec.sender],
                    cycle_time=None if spec.role == NMT else cycle_ms,
                    comment=_CONTROL_COMMENTS[spec.role],
                )
            )
            continue
        tick_bits = FD_TICK_BITS if fd else CLASSIC_TICK_BITS
        signals = [Signal("tick", 0, tick_bits, comment="tick counter k" if fd else "tick counter k mod 65536")]
        start = tick_bits
        for channel, signal_name in zip(spec.channels, spec.signals):
            if fd:
                length, conversion, signed = 64, BaseConversion.factory(1.0, 0.0, is_float=True), False
            else:
                length, conversion, signed = signal_bits(channel), BaseConversion.factory(channel.resolution, 0.0), True
            signals.append(
                Signal(
                    signal_name,
                    start,
                    length,
                    is_signed=signed,
                    conversion=conversion,
                    minimum=channel.minimum,
                    maximum=channel.maximum,
                    unit=channel.unit,
                    comment=channel.description or None,
                )
            )
            start += length
        nbytes = (start + 7) // 8
        messages.append(
            Message(
                spec.frame_id,
                spec.name,
                _fd_length(nbytes) if fd else nbytes,
                signals,
                senders=[spec.sender],
                is_fd=fd,
                cycle_time=cycle_ms,
            )
        )
    nodes = sorted({spec.sender for spec in specs})
    bus_type = DbcAttributeDefinition("BusType", default_value="CAN", type_name="STRING")
    attributes: OrderedDict[str, DbcAttributeType] = OrderedDict(
        BusType=DbcAttribute("CAN FD" if fd else "CAN", bus_type)
    )
    definitions: OrderedDict[str, DbcAttributeDefinitionType] = OrderedDict(BusType=bus_type)
    if fd:  # Vector's attribute for the data-phase bit rate
        fd_rate = DbcAttributeDefinition(
            "BaudrateCANFD", default_value=2_000_000, type_name="INT", minimum=0, maximum=16_000_000
        )
        attributes["BaudrateCANFD"] = DbcAttribute(data_bitrate, fd_rate)
        definitions["BaudrateCANFD"] = fd_rate
    bus = Bus("cosim", baudrate=bitrate, fd_baudrate=data_bitrate if fd else None)
    return Database(
        messages,
        [Node(n) for n in nodes],
        buses=[bus],
        version="cosim",
        dbc_specifics=DbcSpecifics(attributes=attributes, attribute_definitions=definitions),
    )


def _bus_type(database: Database) -> str:
    attribute = database.dbc.attributes.get("BusType") if database.dbc else None
    return str(attribute.value) if attribute is not None else "CAN"  # a STRING attribute


def _role(message: Message) -> Role:
    sender = message.senders[0] if message.senders else ""
    if message.name == "NMT":
        return NMT
    if message.name == "SYNC":
        return SYNC
    if message.name.startswith(MESSAGE_PREFIX[HEARTBEAT] + "_"):
        return HEARTBEAT
    if sender == PLANT:
        return SENSOR
    if sender == CONTROLLER:
        return COMMAND if message.name.startswith(MESSAGE_PREFIX[COMMAND] + "_") else CONTROL
    if message.name.startswith(MESSAGE_PREFIX[ESTIMATE] + "_"):
        return ESTIMATE
    return CLIENT


def _spec_from_message(message: Message) -> MessageSpec:
    role = _role(message)
    sender = message.senders[0] if message.senders else "unknown"
    if role in _CONTROL_LAYOUT:
        return MessageSpec(
            message.name, message.frame_id, sender, role, (), tuple(name for name, *_ in _CONTROL_LAYOUT[role])
        )
    prefix = SIGNAL_PREFIX.get(role, "")
    channels, names = [], []
    for signal in sorted(message.signals, key=lambda s: s.start):
        if signal.name == "tick":
            continue
        comment = signal.comment if isinstance(signal.comment, str) else ""
        resolution = signal.scale if not signal.is_float else 2.0**-52
        channels.append(
            Channel(
                signal.name.removeprefix(prefix),
                signal.unit or "",
                comment,
                signal.minimum if signal.minimum is not None else -math.inf,
                signal.maximum if signal.maximum is not None else math.inf,
                resolution,
            )
        )
        names.append(signal.name)
    return MessageSpec(message.name, message.frame_id, sender, role, tuple(channels), tuple(names))


def load_dbc(text: str) -> cantools.database.can.Database:
    """Parse DBC text (for tools and tests that decode a bus from ``cosim dbc``)."""
    database = cantools.database.load_string(text, database_format="dbc")
    if not isinstance(database, Database):  # a diagnostics (CDD) database: never from the DBC format
        raise CodecError(f"expected a CAN database, got a {type(database).__name__}")
    return database
