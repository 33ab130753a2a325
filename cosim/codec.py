"""The run's CAN database (DBC), generated with cantools, and the encoding of values into frames.

Frame layout
------------
- ``SYNC`` (id 0x080, CANopen's default SYNC COB-ID, sent by ``runner``): ``tick`` (uint32), the
  tick counter k, and ``frames`` (uint8), how many data frames the runner sends for tick k right
  after it (sensor and command frames). A receiver knows it has all of tick k's inputs when it has
  that many; a frame not sent by an injected dropout is simply not counted.
- ``SENSOR_<name>`` (0x100 + i, sent by ``plant``): one frame per sensor, like a smart sensor on
  its own node: ``tick`` and the reading.
- ``COMMAND_<name>`` (0x180 + i, sent by ``controller``): the commanded input of each actuator.
- ``EST_<estimator>_<n>`` (0x200 + 0x20·e + n, sent by the estimator): its estimate x̂_k
  (``xhat_<state>``), packed into as few frames as fit.

Every data frame carries ``tick``: k mod 2¹⁶ in classic CAN (16 bits), k in CAN FD (32 bits).
Classic CAN signals are scaled signed integers whose resolution and range come from the plant
module (or the scenario's overrides); CAN FD signals are float64. A value outside its declared
range, or not finite, is a CodecError naming the signal: never silently wrapped or clipped.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass

import can
import cantools
from cantools.database.can import Bus, Database, Message, Node, Signal
from cantools.database.can.formats.dbc.dbc_attribute import DbcAttribute
from cantools.database.can.formats.dbc.dbc_attribute_definition import DbcAttributeDefinition
from cantools.database.can.formats.dbc.dbc_specifics import DbcSpecifics
from cantools.database.conversion import BaseConversion

from cosim.errors import CodecError
from mjcf import Channel

SYNC_ID = 0x080
SENSOR_BASE = 0x100
COMMAND_BASE = 0x180
ESTIMATE_BASE = 0x200
ESTIMATE_STRIDE = 0x20

CLASSIC_TICK_BITS = 16
FD_TICK_BITS = 32
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)

SYNC, SENSOR, COMMAND, ESTIMATE = "sync", "sensor", "command", "estimate"
RUNNER, PLANT, CONTROLLER = "runner", "plant", "controller"

#: The scenario table that overrides a channel's range, per message role.
OVERRIDE_TABLE = {SENSOR: "sensors", COMMAND: "actuators", ESTIMATE: "states"}
#: Identifier blocks: [first, end) per role. Estimators get ESTIMATE_STRIDE ids each.
ID_BLOCKS = {SENSOR: (SENSOR_BASE, COMMAND_BASE), COMMAND: (COMMAND_BASE, ESTIMATE_BASE), ESTIMATE: (ESTIMATE_BASE, 0x700)}


@dataclass(frozen=True)
class MessageSpec:
    """One DBC message: its name, id, sending node, role, and the channels its signals carry."""

    name: str
    frame_id: int
    sender: str
    role: str
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
    prefix: str, base_id: int, sender: str, role: str, channels: Sequence[Channel], signal_prefix: str, fd: bool
) -> list[MessageSpec]:
    """Lay channels out in as few frames as fit, in order: 8-byte classic frames of scaled integers
    after a 16-bit tick, or 64-byte FD frames of float64 after a 32-bit tick."""
    capacity = 64 * 8 - FD_TICK_BITS if fd else 64 - CLASSIC_TICK_BITS
    groups: list[list[Channel]] = [[]]
    used = 0
    for channel in channels:
        bits = 64 if fd else signal_bits(channel)
        if bits > capacity:
            raise CodecError(
                f"signal {signal_prefix}{channel.name} needs {bits} bits at resolution {channel.resolution:g} "
                f"{channel.unit} over [{channel.minimum:g}, {channel.maximum:g}], and at most {capacity} fit a classic "
                f"frame: set a coarser resolution or a narrower range with [bus.{OVERRIDE_TABLE[role]}.{channel.name}], "
                f"or use CAN FD (bus.fd = true)"
            )
        if used + bits > capacity:
            groups.append([])
            used = 0
        groups[-1].append(channel)
        used += bits
    specs = []
    for n, group in enumerate(groups):
        name = prefix if len(groups) == 1 else f"{prefix}_{n}"
        specs.append(
            MessageSpec(name, base_id + n, sender, role, tuple(group), tuple(signal_prefix + c.name for c in group))
        )
    return specs


class Codec:
    """The CAN database of one run, and fast, range-checked encoding and decoding of its frames.

    Built from the transmitted sensors, the actuators and each estimator's output channels.
    ``fd`` selects CAN FD (float64 signals) or classic CAN (scaled integers).
    """

    def __init__(
        self,
        sensors: Sequence[Channel],
        actuators: Sequence[Channel],
        estimators: dict[str, Sequence[Channel]],
        *,
        fd: bool = False,
        bitrate: int = 500_000,
        data_bitrate: int = 2_000_000,
        cycle_time: float | None = None,
    ) -> None:
        self.fd = fd
        self.bitrate = bitrate
        self.data_bitrate = data_bitrate
        for role, count in ((SENSOR, len(sensors)), (COMMAND, len(actuators)), (ESTIMATE, len(estimators) * ESTIMATE_STRIDE)):
            first, end = ID_BLOCKS[role]
            if count > end - first:
                what = {SENSOR: "sensors", COMMAND: "actuators", ESTIMATE: "estimators"}[role]
                limit = (end - first) // (ESTIMATE_STRIDE if role == ESTIMATE else 1)
                raise CodecError(f"too many {what} for the bus: at most {limit} fit ids 0x{first:03X}-0x{end - 1:03X}")
        specs = [MessageSpec("SYNC", SYNC_ID, RUNNER, SYNC, (), ("tick", "frames"))]
        for i, channel in enumerate(sensors):
            specs += pack_channels(f"SENSOR_{channel.name}", SENSOR_BASE + i, PLANT, SENSOR, [channel], "", fd)
        for i, channel in enumerate(actuators):
            specs += pack_channels(f"COMMAND_{channel.name}", COMMAND_BASE + i, CONTROLLER, COMMAND, [channel], "", fd)
        for e, (name, channels) in enumerate(estimators.items()):
            base = ESTIMATE_BASE + ESTIMATE_STRIDE * e
            packed = pack_channels(f"EST_{name}", base, name, ESTIMATE, channels, "xhat_", fd)
            if len(packed) > ESTIMATE_STRIDE:
                raise CodecError(f"estimator {name} needs {len(packed)} frames per tick; at most {ESTIMATE_STRIDE} fit its id block")
            specs += packed
        self.specs: dict[str, MessageSpec] = {spec.name: spec for spec in specs}
        self._by_id: dict[int, MessageSpec] = {spec.frame_id: spec for spec in specs}
        cycle_ms = None if cycle_time is None or cycle_time < 1e-3 else int(round(cycle_time * 1000))
        self.database = self._database(specs, cycle_ms)
        self._messages: dict[str, Message] = {m.name: m for m in self.database.messages}
        self.tick_modulus = 2**FD_TICK_BITS if fd else 2**CLASSIC_TICK_BITS

    # -- database -------------------------------------------------------------------------------

    def _database(self, specs: list[MessageSpec], cycle_ms: int | None) -> Database:
        messages = []
        for spec in specs:
            if spec.role == SYNC:
                signals = [
                    Signal("tick", 0, 32, comment="tick counter k"),
                    Signal("frames", 32, 8, comment="data frames the runner sends for tick k after this SYNC"),
                ]
                messages.append(
                    Message(SYNC_ID, "SYNC", 5, signals, senders=[RUNNER], cycle_time=cycle_ms, comment="start of tick k")
                )
                continue
            tick_bits = FD_TICK_BITS if self.fd else CLASSIC_TICK_BITS
            tick_comment = "tick counter k" if self.fd else "tick counter k mod 65536"
            signals = [Signal("tick", 0, tick_bits, comment=tick_comment)]
            start = tick_bits
            for channel, signal_name in zip(spec.channels, spec.signals):
                if self.fd:
                    length, conversion = 64, BaseConversion.factory(1.0, 0.0, is_float=True)
                    signed = False
                else:
                    length, conversion = signal_bits(channel), BaseConversion.factory(channel.resolution, 0.0)
                    signed = True
                signals.append(
                    Signal(
                        signal_name, start, length, is_signed=signed, conversion=conversion,
                        minimum=channel.minimum, maximum=channel.maximum, unit=channel.unit,
                        comment=channel.description,
                    )
                )
                start += length
            nbytes = (start + 7) // 8
            length = _fd_length(nbytes) if self.fd else nbytes
            messages.append(
                Message(
                    spec.frame_id, spec.name, length, signals, senders=[spec.sender], is_fd=self.fd,
                    cycle_time=cycle_ms,
                )
            )
        nodes = sorted({spec.sender for spec in specs})
        bus_type = DbcAttributeDefinition("BusType", default_value="CAN", type_name="STRING")
        attributes = OrderedDict(BusType=DbcAttribute("CAN FD" if self.fd else "CAN", bus_type))
        definitions = OrderedDict(BusType=bus_type)
        if self.fd:  # Vector's attribute for the data-phase bit rate
            fd_rate = DbcAttributeDefinition("BaudrateCANFD", default_value=2_000_000, type_name="INT", minimum=0, maximum=16_000_000)
            attributes["BaudrateCANFD"] = DbcAttribute(self.data_bitrate, fd_rate)
            definitions["BaudrateCANFD"] = fd_rate
        dbc = DbcSpecifics(attributes=attributes, attribute_definitions=definitions)
        bus = Bus("cosim", baudrate=self.bitrate, fd_baudrate=self.data_bitrate if self.fd else None)
        return Database(messages, [Node(n) for n in nodes], buses=[bus], version="cosim", dbc_specifics=dbc)

    @property
    def dbc(self) -> str:
        """The database as DBC text (CAN FD frames are marked with VFrameFormat)."""
        return self.database.as_dbc_string()

    def messages(self, role: str | None = None, sender: str | None = None) -> list[MessageSpec]:
        """Message specs, optionally only those of one role or sender, in id order."""
        return sorted(
            (s for s in self.specs.values() if (role is None or s.role == role) and (sender is None or s.sender == sender)),
            key=lambda s: s.frame_id,
        )

    # -- frames ---------------------------------------------------------------------------------

    def sync(self, tick: int, frames: int) -> can.Message:
        if not 0 <= frames <= 255:
            raise CodecError(f"tick {tick} has {frames} data frames; a SYNC can announce at most 255")
        data = self._messages["SYNC"].encode({"tick": tick % 2**32, "frames": frames}, strict=False)
        return can.Message(arbitration_id=SYNC_ID, data=data, is_extended_id=False)

    def encode(self, name: str, tick: int, values: Sequence[float]) -> can.Message:
        """The frame of message ``name`` for tick k carrying ``values`` (one per signal, in order)."""
        spec = self.specs[name]
        payload: dict[str, float] = {"tick": tick % self.tick_modulus}
        for channel, signal_name, value in zip(spec.channels, spec.signals, values, strict=True):
            if not (channel.minimum <= value <= channel.maximum):  # also rejects NaN
                raise CodecError(_range_message(spec, signal_name, channel, value, tick))
            payload[signal_name] = float(value)
        data = self._messages[name].encode(payload, strict=False)
        return can.Message(
            arbitration_id=spec.frame_id, data=data, is_extended_id=False, is_fd=self.fd, bitrate_switch=self.fd
        )

    def spec_of(self, frame: can.Message) -> MessageSpec | None:
        return None if frame.is_extended_id else self._by_id.get(frame.arbitration_id)

    def decode(self, frame: can.Message) -> Decoded | None:
        """The decoded frame, or None for a frame this database does not describe."""
        spec = self.spec_of(frame)
        if spec is None:
            return None
        message = self._messages[spec.name]
        try:
            values = message.decode(bytes(frame.data), decode_choices=False)
        except Exception as error:  # cantools raises several types for short or malformed data
            raise CodecError(f"frame 0x{frame.arbitration_id:03X} ({spec.name}) cannot be decoded: {error}") from None
        tick = int(values.pop("tick"))
        return Decoded(spec, tick, values)


def _range_message(spec: MessageSpec, signal: str, channel: Channel, value: float, tick: int) -> str:
    where = f"signal {spec.name}.{signal} at tick {tick}"
    if math.isnan(value):
        return f"{where} is not a number (NaN) and cannot be sent"
    return (
        f"{where} = {value:g} {channel.unit} is outside its declared range "
        f"[{channel.minimum:g}, {channel.maximum:g}] {channel.unit}: widen it in the scenario with "
        f"[bus.{OVERRIDE_TABLE[spec.role]}.{channel.name}] minimum = ... / maximum = ..., "
        f"or find out why the value left it"
    )


def load_dbc(text: str) -> cantools.database.can.Database:
    """Parse DBC text (for tools and tests that decode a bus from ``cosim dbc``)."""
    return cantools.database.load_string(text, database_format="dbc")
