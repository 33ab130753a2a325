"""The run's CAN database (DBC): its frame layout, built with cantools and read back from DBC text.

Frame layout (CANopen-flavoured; ids in hex)
---------------------------------------------
- ``NMT`` (0x000, sent by ``runner``): network management, ``command`` (1 start, 2 stop) and
  ``node`` (0: all nodes), then ``mac`` (48 bits). The runner sends "stop all" when a run ends.
- ``SYNC`` (0x080, CANopen's default SYNC COB-ID, sent by ``runner``): ``tick`` (uint32), the
  tick counter k, and ``frames`` (uint8), how many data frames the runner sends for tick k right
  after it (sensor and command frames), then ``mac`` (24 bits). A receiver knows it has all of tick
  k's inputs when it has that many; a frame not sent by an injected dropout is simply not counted.
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
  (CANopen NMT state: 0 boot-up, 4 stopped, 5 operational), ``tick`` (mod 2¹⁶), ``frames`` (data
  frames the node sent for that tick), ``lost`` (frames the node found missing so far, mod 2⁸)
  and ``mac`` (24 bits). A node sends its boot-up heartbeat when it joins and one operational
  heartbeat after its frames of every tick: that is what the runner waits for in lockstep, and
  what per-sender loss counting rests on.

Every data frame carries ``tick``: k mod 2¹⁶ in classic CAN (16 bits), k in CAN FD (32 bits).
Classic CAN signals are scaled signed integers whose resolution and range come from the plant
module (or the scenario's overrides); CAN FD signals are float64. NMT, SYNC and heartbeats are
classic frames of 8 bytes on either bus; their ``mac`` (``cosim.bus.control_frames``) is in the DBC
but no signal of their spec.

The DBC text is complete: ``spec_from_message`` rebuilds every message's spec from it, which is
how node processes and clients get their codec. A secured DBC (``cosim.bus.secoc``) has a trailer
of two signals appended to its data messages; ``strip_secoc_trailer`` takes them out again. The
codec (``cosim.bus.codec``) and the authentication both build on this module, not on each other.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Protocol

import cantools
from cantools.database.can import Bus, Database, Message, Node, Signal
from cantools.database.can.formats.dbc.dbc_attribute import DbcAttribute
from cantools.database.can.formats.dbc.dbc_attribute_definition import DbcAttributeDefinition
from cantools.database.can.formats.dbc.dbc_specifics import DbcSpecifics
from cantools.database.conversion import BaseConversion

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
HEARTBEAT_TICK_BITS = 16
CONTROL_MAC = "mac"
"""The signal of a control frame's MAC (``cosim.bus.control_frames``): in the DBC, never among a spec's signals."""
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


class DatabaseView(Protocol):
    """What a participant knows of the run's database: its message specs by name, and the secured
    ids with the byte where their SecOC trailer starts (empty: not secured)."""

    @property
    def specs(self) -> Mapping[str, MessageSpec]: ...

    @property
    def secoc_trailers(self) -> Mapping[int, int]: ...


def signal_bits(channel: Channel) -> int:
    """Bits of a signed integer signal that spans the channel's range at its resolution."""
    span = max(abs(channel.minimum), abs(channel.maximum)) / channel.resolution
    return math.ceil(math.log2(span + 1.0)) + 1


def fd_length(nbytes: int) -> int:
    """The shortest CAN FD data length that holds ``nbytes`` bytes."""
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


def layout_messages(
    sensors: Sequence[Channel],
    actuators: Sequence[Channel],
    estimators: Mapping[str, Sequence[Channel]],
    diagnostics: Mapping[str, Sequence[Channel]],
    clients: Mapping[str, Sequence[Channel]],
    controller: Sequence[Channel] | None,
    fd: bool,
) -> list[MessageSpec]:
    """Every message of a run, laid out in its id block: the runner's NMT and SYNC, a frame per
    sensor and per actuator, the controller's status, each estimator's estimate and diagnostics,
    each client's signals, and a heartbeat per node (estimators get node ids 1, 2, …, then the
    clients, then the controller)."""
    _check_capacity(len(sensors), len(actuators), len(estimators), len(clients), controller is not None)
    nodes = [*estimators, *clients, *([CONTROLLER] if controller is not None else [])]
    if len(set(nodes)) != len(nodes):
        raise CodecError(f"estimator, client and controller names must differ: {', '.join(nodes)}")
    specs = [
        MessageSpec("NMT", NMT_ID, RUNNER, NMT, (), _control_signals(NMT)),
        MessageSpec("SYNC", SYNC_ID, RUNNER, SYNC, (), _control_signals(SYNC)),
    ]
    for i, channel in enumerate(sensors):
        specs += pack_channels(sensor_message(channel.name), SENSOR_BASE + i, PLANT, SENSOR, [channel], fd)
    for i, channel in enumerate(actuators):
        specs += pack_channels(command_message(channel.name), COMMAND_BASE + i, CONTROLLER, COMMAND, [channel], fd)
    if controller:
        names = [c.name for c in controller]
        specs += pack_channels(MESSAGE_PREFIX[CONTROL], CONTROL_BASE, CONTROLLER, CONTROL, list(controller), fd, names)
    for e, (name, channels) in enumerate(estimators.items()):
        extra = list(diagnostics.get(name, ()))
        signals = [estimate_signal(c.name) for c in channels] + [c.name for c in extra]
        specs += _node_messages(name, ESTIMATE, ESTIMATE_BASE + ESTIMATE_STRIDE * e, [*channels, *extra], signals, fd)
    for c, (name, channels) in enumerate(clients.items()):
        signals = [channel.name for channel in channels]
        specs += _node_messages(name, CLIENT, CLIENT_BASE + CLIENT_STRIDE * c, list(channels), signals, fd)
    heartbeat_signals = _control_signals(HEARTBEAT)
    for node_id, name in enumerate(nodes, start=1):
        specs.append(
            MessageSpec(heartbeat_message(name), HEARTBEAT_BASE + node_id, name, HEARTBEAT, (), heartbeat_signals)
        )
    return specs


def _check_capacity(sensors: int, actuators: int, estimators: int, clients: int, controller: bool) -> None:
    counts = {
        SENSOR: (sensors, 1, "sensors"),
        COMMAND: (actuators, 1, "actuators"),
        ESTIMATE: (estimators, ESTIMATE_STRIDE, "estimators"),
        CLIENT: (clients, CLIENT_STRIDE, "clients"),
    }
    for role, (count, stride, what) in counts.items():
        first, end = ID_BLOCKS[role]
        if count * stride > end - first:
            raise CodecError(
                f"too many {what} for the bus: at most {(end - first) // stride} fit ids 0x{first:03X}-0x{end - 1:03X}"
            )
    if controller and actuators > CONTROL_BASE - COMMAND_BASE:
        raise CodecError(
            f"too many actuators for a controller node: at most {CONTROL_BASE - COMMAND_BASE} fit ids "
            f"0x{COMMAND_BASE:03X}-0x{CONTROL_BASE - 1:03X}"
        )


def _node_messages(
    name: str, role: Role, base_id: int, channels: list[Channel], signals: list[str], fd: bool
) -> list[MessageSpec]:
    """An estimator's or a client's data messages, within its block of ids."""
    stride = ESTIMATE_STRIDE if role == ESTIMATE else CLIENT_STRIDE
    packed = pack_channels(f"{MESSAGE_PREFIX[role]}_{name}", base_id, name, role, channels, fd, signals)
    if len(packed) > stride:
        raise CodecError(f"{name} needs {len(packed)} frames per tick; at most {stride} fit its id block")
    return packed


# -- the DBC -----------------------------------------------------------------------------------


_CONTROL_LAYOUT = {
    NMT: [
        ("command", 0, 8, "NMT command: 1 start, 2 stop"),
        ("node", 8, 8, "addressed node id, 0 for all"),
        (CONTROL_MAC, 16, 48, "AES-CMAC under the runner's control key, truncated to 48 bits"),
    ],
    SYNC: [
        ("tick", 0, 32, "tick counter k"),
        ("frames", 32, 8, "data frames the runner sends for tick k after this SYNC"),
        (CONTROL_MAC, 40, 24, "AES-CMAC under the runner's control key, truncated to 24 bits"),
    ],
    HEARTBEAT: [
        ("state", 0, 8, "NMT state: 0 boot-up, 4 stopped, 5 operational"),
        ("tick", 8, HEARTBEAT_TICK_BITS, "the tick this heartbeat closes, mod 65536"),
        ("frames", 24, 8, "data frames the node sent for that tick"),
        ("lost", 32, 8, "frames the node found missing so far, mod 256"),
        (CONTROL_MAC, 40, 24, "AES-CMAC under the node's control key, truncated to 24 bits"),
    ],
}


def _control_signals(role: Role) -> tuple[str, ...]:
    """A control message's signals as its spec names them (its MAC is not one of them)."""
    return tuple(name for name, *_ in _CONTROL_LAYOUT[role] if name != CONTROL_MAC)


_CONTROL_COMMENTS = {NMT: "network management (CANopen NMT)", SYNC: "start of tick k", HEARTBEAT: "node heartbeat"}


def build_database(
    specs: Sequence[MessageSpec], fd: bool, bitrate: int, data_bitrate: int, cycle_ms: int | None
) -> Database:
    """The cantools database of the messages, on a bus named ``cosim`` at the given bit rates
    (``cycle_ms``: every cyclic message's GenMsgCycleTime)."""
    messages = [
        _control_message(spec, cycle_ms) if spec.role in _CONTROL_LAYOUT else _data_message(spec, fd, cycle_ms)
        for spec in specs
    ]
    bus = Bus("cosim", baudrate=bitrate, fd_baudrate=data_bitrate if fd else None)
    return Database(
        messages,
        [Node(n) for n in sorted({spec.sender for spec in specs})],
        buses=[bus],
        version="cosim",
        dbc_specifics=_dbc_specifics(fd, data_bitrate),
    )


def _control_message(spec: MessageSpec, cycle_ms: int | None) -> Message:
    signals = [
        Signal(name, start, length, comment=comment) for name, start, length, comment in _CONTROL_LAYOUT[spec.role]
    ]
    return Message(
        spec.frame_id,
        spec.name,
        (max(s.start + s.length for s in signals) + 7) // 8,
        signals,
        senders=[spec.sender],
        cycle_time=None if spec.role == NMT else cycle_ms,
        comment=_CONTROL_COMMENTS[spec.role],
    )


def _data_message(spec: MessageSpec, fd: bool, cycle_ms: int | None) -> Message:
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
    length = fd_length(nbytes) if fd else nbytes
    return Message(spec.frame_id, spec.name, length, signals, senders=[spec.sender], is_fd=fd, cycle_time=cycle_ms)


def _dbc_specifics(fd: bool, data_bitrate: int) -> DbcSpecifics:
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
    return DbcSpecifics(attributes=attributes, attribute_definitions=definitions)


def bus_type(database: Database) -> str:
    """The database's BusType attribute: "CAN FD" or "CAN"."""
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


def message_roles(database: Database) -> dict[str, tuple[Role, str]]:
    """Each message's role and sender, by name, as ``spec_from_message`` finds them (for any DBC,
    including one the codec cannot compile)."""
    return {m.name: (_role(m), m.senders[0] if m.senders else "unknown") for m in database.messages}


def spec_from_message(message: Message) -> MessageSpec:
    """The spec of a message read from a DBC (its role from its name and sender)."""
    role = _role(message)
    sender = message.senders[0] if message.senders else "unknown"
    if message.is_extended_frame:
        raise CodecError(
            f"DBC message {message.name} has an extended (29-bit) id, 0x{message.frame_id:X}; cosim's bus codec "
            "lays its messages out on standard ids ('cosim monitor --dbc' and 'cosim import' decode any DBC)"
        )
    if role in _CONTROL_LAYOUT:
        return MessageSpec(message.name, message.frame_id, sender, role, (), _control_signals(role))
    prefix = SIGNAL_PREFIX.get(role, "")
    channels, names = [], []
    for signal in sorted(message.signals, key=lambda s: s.start):
        if signal.name == "tick":
            continue
        channels.append(_channel(message, signal, signal.name.removeprefix(prefix)))
        names.append(signal.name)
    return MessageSpec(message.name, message.frame_id, sender, role, tuple(channels), tuple(names))


def _channel(message: Message, signal: Signal, name: str) -> Channel:
    """The channel a DBC signal carries: its range (none where the DBC gives none, or gives one of
    no width, as ``[0|0]`` says "not given") and its step, the factor's magnitude (a negative
    factor is a valid DBC); a CodecError naming the message and the signal for a range whose
    minimum is above its maximum."""
    comment = signal.comment if isinstance(signal.comment, str) else ""
    resolution = abs(signal.scale) if not signal.is_float else 2.0**-52
    minimum = signal.minimum if signal.minimum is not None else -math.inf
    maximum = signal.maximum if signal.maximum is not None else math.inf
    if minimum == maximum:
        minimum, maximum = -math.inf, math.inf
    where = f"DBC message {message.name}, signal {signal.name}"
    if not minimum < maximum:
        raise CodecError(f"{where}: its range [{minimum:g}|{maximum:g}] holds no value (minimum above maximum)")
    if not resolution > 0:
        raise CodecError(f"{where}: its factor is 0, so it carries no value")
    return Channel(name, signal.unit or "", comment, minimum, maximum, resolution)


def control_mac_start(frame_id: int) -> int | None:
    """The byte where a control frame's MAC starts, by its id (None for any other frame): the
    bytes that differ between two runs of a seed, each signed with its own key."""
    if frame_id == NMT_ID:
        role = NMT
    elif frame_id == SYNC_ID:
        role = SYNC
    elif HEARTBEAT_BASE < frame_id <= HEARTBEAT_BASE + MAX_NODE_ID:
        role = HEARTBEAT
    else:
        return None
    return next(start for name, start, *_ in _CONTROL_LAYOUT[role] if name == CONTROL_MAC) // 8


@dataclass(frozen=True)
class ControlFields:
    """Where a control message carries its tick counter (None: NMT) and its MAC: (first byte, bytes)."""

    tick: tuple[int, int] | None
    mac: tuple[int, int]


def control_fields(message: Message) -> ControlFields | None:
    """The tick and MAC fields of an authenticated control message (None: no MAC in the DBC)."""
    signals = {signal.name: signal for signal in message.signals}
    mac, tick = signals.get(CONTROL_MAC), signals.get("tick")
    if mac is None or _role(message) not in _CONTROL_LAYOUT:
        return None
    return ControlFields(
        None if tick is None else (tick.start // 8, tick.length // 8), (mac.start // 8, mac.length // 8)
    )


def load_dbc(text: str, strict: bool = True) -> cantools.database.can.Database:
    """Parse DBC text (for tools and tests that decode a bus from ``cosim dbc``); ``strict=False``
    takes what cantools takes of a vehicle's DBC, overlapping signals and all. A text cantools
    refuses is a CodecError with its reason in one line."""
    try:
        database = cantools.database.load_string(text, database_format="dbc", strict=strict)
    except Exception as error:  # noqa: BLE001 - cantools raises several parse error types
        raise CodecError(f"cantools cannot read it as a DBC: {refusal(error)}") from None
    if not isinstance(database, Database):  # a diagnostics (CDD) database: never from the DBC format
        raise CodecError(f"expected a CAN database, got a {type(database).__name__}")
    return database


def refusal(error: Exception) -> str:
    """cantools' reason for refusing a DBC, in one line (its messages can span several)."""
    text = " ".join(str(error).split()) or type(error).__name__
    return text.removeprefix('DBC: "').removesuffix('"') if text.startswith('DBC: "') else text


SECOC_SIGNALS = ("secoc_fv", "secoc_mac")
"""The signals of a secured message's SecOC trailer: freshness value and MAC (``cosim.bus.secoc``)."""


def strip_secoc_trailer(database: Database) -> dict[int, int]:
    """Take the SecOC trailer's signals out of a secured database's messages (their length stays);
    the byte where each secured id's trailer starts (empty: the database is not secured)."""
    trailers: dict[int, int] = {}
    for message in database.messages:
        found = [signal for signal in message.signals if signal.name in SECOC_SIGNALS]
        if not found:
            continue
        trailers[message.frame_id] = min(signal.start for signal in found) // 8
        for signal in found:
            message.signals.remove(signal)
        message.refresh()
    if trailers:
        database.refresh()
    return trailers
