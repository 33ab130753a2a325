"""Encoding of values into the run's CAN frames, and decoding of frames into values.

The database itself (the frame layout, ids, roles, the DBC text) is ``cosim.bus.dbc``; this module
compiles each of its messages into a packer and checks every value against its signal's declared
range. A value outside its declared range, or not finite, is a CodecError naming the signal: never
silently wrapped or clipped.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import can
import numpy as np
from cantools.database.can import Database, Message

from cosim.bus.dbc import (
    BOOTUP,
    CLASSIC_TICK_BITS,
    CLIENT,
    COMMAND,
    CONTROL,
    CONTROL_MAC,
    CONTROLLER,
    ESTIMATE,
    FD_TICK_BITS,
    HEARTBEAT,
    HEARTBEAT_BASE,
    HEARTBEAT_TICK_BITS,
    MESSAGE_PREFIX,
    NMT,
    NMT_STOP,
    OPERATIONAL,
    OVERRIDE_TABLE,
    PLANT,
    RUNNER,
    SENSOR,
    STOPPED,
    SYNC,
    SYNC_ID,
    ControlFields,
    MessageSpec,
    build_database,
    bus_type,
    command_message,
    control_fields,
    estimate_signal,
    estimated_state,
    heartbeat_message,
    layout_messages,
    load_dbc,
    sensor_message,
    signal_bits,
    spec_from_message,
    strip_secoc_trailer,
)
from cosim.bus.packing import CarriedValues, Packer, RowsPacker, rows_packer
from cosim.bus.signals import Channel
from cosim.errors import CodecError

__all__ = [  # the database's names a codec's users need, with the codec
    "BOOTUP",
    "CLASSIC_TICK_BITS",
    "CLIENT",
    "COMMAND",
    "CONTROL",
    "CONTROLLER",
    "ESTIMATE",
    "HEARTBEAT",
    "MESSAGE_PREFIX",
    "NMT",
    "NMT_STOP",
    "OPERATIONAL",
    "PLANT",
    "RUNNER",
    "SENSOR",
    "STOPPED",
    "SYNC",
    "SYNC_ID",
    "Codec",
    "Decoded",
    "MessageSpec",
    "estimate_signal",
    "estimated_state",
    "load_dbc",
    "saturated",
    "signal_bits",
]


@dataclass(frozen=True)
class Decoded:
    """A decoded frame: its message, the tick counter it carries, and its physical values."""

    spec: MessageSpec
    tick: int
    values: dict[str, float]


class _RowsGroup:
    """What ``Codec.encode_rows`` needs of some messages, as arrays: their packer (each message's
    tick counter, then its signals), the signals' ranges, their columns among the packer's fields,
    the message of each, and each message's signals' place among the values and its length."""

    def __init__(self, packer: RowsPacker, specs: Sequence[MessageSpec], lengths: Sequence[int]) -> None:
        self.packer, self.specs = packer, list(specs)
        channels = [c for spec in specs for c in spec.channels]
        self.low, self.high = ranges(specs)
        self.message_of = np.repeat(np.arange(len(specs)), [len(spec.signals) for spec in specs])
        counters = np.cumsum([0, *(1 + len(spec.signals) for spec in specs[:-1])])
        self.signals = np.delete(np.arange(len(channels) + len(specs)), counters)
        self.width = len(channels) + len(specs)
        ends = np.cumsum([len(spec.signals) for spec in specs]).tolist()
        self.layout = [(spec, end - len(spec.signals), end) for spec, end in zip(specs, ends)]
        self.lengths = list(lengths)


class Codec:
    """The CAN database of one run, and fast, range-checked encoding and decoding of its frames.

    Built from the transmitted sensors, the actuators, each estimator's output channels and each
    declared client's signals, laid out by ``cosim.bus.dbc``; ``fd`` selects CAN FD (float64
    signals) or classic CAN (scaled integers). Estimators get node ids 1, 2, … in order, then the
    clients, then the controller: with ``controller`` (its diagnostic channels, possibly none) the
    commands come from a ``controller`` node, which has a heartbeat and a CONTROL_STATUS message.
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
        specs = layout_messages(
            sensors, actuators, estimators, dict(diagnostics or {}), dict(clients or {}), controller, fd
        )
        cycle_ms = None if cycle_time is None or cycle_time < 1e-3 else int(round(cycle_time * 1000))
        self._setup(build_database(specs, fd, bitrate, data_bitrate, cycle_ms), specs, fd)

    @classmethod
    def from_dbc(cls, text: str) -> Codec:
        """The codec described by a DBC written by ``Codec.dbc`` (or ``cosim dbc``).

        A codec does not change once built, so one text's codec is shared: the nodes of a run
        in one process, and the runs of a campaign worker, read the same DBC (parsing it and
        compiling its packers costs some 25 ms). Its ``database``, ``specs`` and id maps are
        therefore read-only to its users, in every thread."""
        return _codec_of(text) if cls is Codec else cls._parse(text)

    @classmethod
    def _parse(cls, text: str) -> Codec:
        database = load_dbc(text)
        # The SecOC trailer is no signal of the codec: taken out, the secured frames keep their length.
        trailers = strip_secoc_trailer(database)
        fd = any(m.is_fd for m in database.messages) or bus_type(database) == "CAN FD"
        specs = [spec_from_message(m) for m in database.messages]
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
        # A control frame's MAC comes last and is no value of its spec (``cosim.bus.control_frames`` fills it).
        self._packers: dict[str, Packer] = {}
        self._heartbeats: dict[tuple[Any, ...], bytes] = {}  # the payloads of the last heartbeats encoded
        self._groups: dict[tuple[str, ...], _RowsGroup | None] = {}  # ``encode_rows``' arrays, by messages
        #: Control ids with a MAC: the spec, and where its tick and MAC are.
        self.control_macs: dict[int, tuple[MessageSpec, ControlFields]] = {}
        for spec in specs:
            message = self._messages[spec.name]
            has_tick = any(signal.name == "tick" for signal in message.signals) and "tick" not in spec.signals
            order = ("tick", *spec.signals) if has_tick else spec.signals
            fields = control_fields(message)
            if fields is not None:  # a DBC written before control frames were authenticated has none
                order = (*order, CONTROL_MAC)
                self.control_macs[spec.frame_id] = (spec, fields)
            self._packers[spec.name] = Packer(message, order)
        # id -> (spec, packer, where the tick counter is among the packer's values, the other signals)
        self._unpacking: dict[int, tuple[MessageSpec, Packer, int | None, tuple[str, ...]]] = {}
        for spec in specs:
            names = self._packers[spec.name].names
            at = names.index("tick") if "tick" in names else None
            others = tuple(name for name in names if name not in ("tick", CONTROL_MAC))
            self._unpacking[spec.frame_id] = (spec, self._packers[spec.name], at, others)
        self.tick_modulus = 2**FD_TICK_BITS if fd else 2**CLASSIC_TICK_BITS
        self.node_ids: dict[str, int] = {
            spec.sender: spec.frame_id - HEARTBEAT_BASE for spec in specs if spec.role == HEARTBEAT
        }

    # -- database -------------------------------------------------------------------------------

    @functools.cached_property
    def dbc(self) -> str:
        """The database as DBC text (CAN FD frames are marked with VFrameFormat; a secured one as it was read).
        Written once per codec: cantools takes some 25 ms to write it, and a run hands it to each of
        its nodes and its log."""
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
        data = packer.encode([values.get(signal, 0) for signal in packer.names])  # the MAC's place left 0
        return can.Message(arbitration_id=spec.frame_id, data=data, is_extended_id=False)

    def sync(self, tick: int, frames: int) -> can.Message:
        if not 0 <= frames <= 255:
            raise CodecError(f"tick {tick} has {frames} data frames; a SYNC can announce at most 255")
        return self._classic("SYNC", {"tick": tick % 2**32, "frames": frames})

    def syncs(self, tick: int, frames: int, count: int) -> list[can.Message]:
        """``count`` frames SYNC(tick) announcing ``frames``, each a message of its own (each is
        signed in place, under its run's key), encoded once."""
        first = self.sync(tick, frames)
        data = bytes(first.data)
        copies = [
            can.Message(arbitration_id=first.arbitration_id, data=data, is_extended_id=False) for _ in range(1, count)
        ]
        return [first, *copies] if count else []

    def nmt(self, command: int, node: int = 0) -> can.Message:
        return self._classic("NMT", {"command": command, "node": node})

    def heartbeat(self, node: str, state: int, tick: int = 0, frames: int = 0, lost: int = 0) -> can.Message:
        """A node's heartbeat closing ``tick`` (carried mod 2¹⁶), with its ``frames`` of that tick
        and the frames it found missing so far (carried mod 2⁸)."""
        values = {"state": state, "tick": tick % 2**HEARTBEAT_TICK_BITS, "frames": min(frames, 255), "lost": lost % 256}
        # the K runs of a batch send one node's heartbeat of a tick with the same values: encoded once
        key = (node, *values.values())
        data = self._heartbeats.get(key)
        if data is not None:
            spec = self.specs[heartbeat_message(node)]
            return can.Message(arbitration_id=spec.frame_id, data=data, is_extended_id=False)
        frame = self._classic(heartbeat_message(node), values)
        if len(self._heartbeats) >= 64:
            self._heartbeats.clear()
        self._heartbeats[key] = bytes(frame.data)
        return frame

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

    def encode_rows(
        self, names: Sequence[str], tick: int, values: np.ndarray, sent: np.ndarray | None = None
    ) -> list[list[tuple[can.Message, Decoded]] | None] | None:
        """``encode_decoded`` of the frames of messages ``names`` for tick k in K rows at once:
        ``values`` (K, every message's signals in turn), ``sent`` (K, messages) which frames each row
        has (None: all). Each row's frames in the order of ``names``, each with what a receiver
        decodes from it: the bytes, values and their types of ``encode_decoded``'s
        (``RowsPacker``). A row is None where one of its values is outside its channel's range or
        not a number (``encode`` names it); all are None where a message is not packed on arrays or
        carries a value as an integer."""
        found = self.rows_payloads(names, tick, values, sent)
        if found is None:
            return None
        payloads, carried, fits = found
        group = self._groups[tuple(names)]
        assert group is not None
        counter, m = tick % self.tick_modulus, len(group.specs)
        on = np.ones((len(values), m), dtype=bool) if sent is None else sent
        data = payloads.tobytes()
        out: list[list[tuple[can.Message, Decoded]] | None] = []
        for i, (row, built, fit) in enumerate(zip(carried.tolist(), on.tolist(), fits.tolist())):
            if not fit:
                out.append(None)
                continue
            frames, at = [], i * m * 8
            for j, (spec, a, b) in enumerate(group.layout):
                if built[j]:
                    frame = self._frame(spec, data[at + 8 * j : at + 8 * j + group.lengths[j]])
                    frames.append((frame, Decoded(spec, counter, dict(zip(spec.signals, row[a:b])))))
            out.append(frames)
        return out

    def rows_payloads(
        self, names: Sequence[str], tick: int, values: np.ndarray, sent: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """What ``encode_rows`` builds its frames from, as arrays: each frame's bytes (K, messages,
        8) uint8 (the first of them its payload; a frame not sent all 0), the values each carries
        (K, every message's signals in turn; a frame not sent: what 0 carries) and whether each row
        fits (its values sent in their ranges). None where ``encode_rows`` gives None."""
        group = self._rows_group(tuple(names))
        if group is None:
            return None
        k, m = len(values), len(group.specs)
        on = np.ones((k, m), dtype=bool) if sent is None else sent
        sends = on[:, group.message_of]
        fits = np.asarray((~sends | ((group.low <= values) & (values <= group.high))).all(axis=1))  # NaN: no fit
        full = np.full((k, group.width), float(tick % self.tick_modulus))
        full[:, group.signals] = np.where(sends & fits[:, None], values, 0.0)  # 0: a frame not built
        words, carried = group.packer.encode_rows(full)
        return words.astype("<u8").view(np.uint8).reshape(k, m, 8), carried[:, group.signals], fits

    def _rows_group(self, names: tuple[str, ...]) -> _RowsGroup | None:
        """``encode_rows``' arrays of these messages (built once), or None where one is not packed
        on arrays (``Packer.packs_rows``), does not carry the tick counter first or carries a
        value as an integer."""
        if names in self._groups:
            return self._groups[names]
        specs = [self.specs[name] for name in names]
        packers = [self._packers[name] for name in names]
        floats = all(
            packer.names == ("tick", *spec.signals) and self._carries_floats(spec, packer)
            for spec, packer in zip(specs, packers)
        )
        rows = rows_packer(packers) if floats else None
        found = self._groups[names] = (
            None if rows is None else _RowsGroup(rows, specs, [packer.length for packer in packers])
        )
        return found

    def _carries_floats(self, spec: MessageSpec, packer: Packer) -> bool:
        """Whether a message's values are carried as floats (``encode_carried``'s type of each: an
        identity conversion of an integer signal carries an int, which ``encode_rows`` does not give)."""
        if not packer.packs_rows:
            return False
        probe = self._payload(spec, 0, [max(c.minimum, min(0.0, c.maximum)) for c in spec.channels])
        return all(type(v) is float for v in packer.encode_carried(probe)[1][1:])

    def carried_of(self, specs: Sequence[MessageSpec]) -> Callable[[np.ndarray], np.ndarray]:
        """The values of these messages' signals, in order, for K frames of each at once: (K,
        signals) in, (K, signals) out as the frames carry them (what ``encode_decoded``'s Decoded
        holds, bit for bit). The values must lie in their ranges (``encode`` checks that)."""
        fields = []
        for spec in specs:
            packer = self._packers[spec.name]
            by_name = dict(zip(packer.names, packer.fields))
            fields += [by_name[signal] for signal in spec.signals]
        return CarriedValues(fields)

    def _payload(self, spec: MessageSpec, tick: int, values: Sequence[float]) -> list[float]:
        """The tick counter and the values, each checked against its channel's range."""
        payload: list[float] = [tick % self.tick_modulus]
        for channel, value in zip(spec.channels, values, strict=True):
            if not (channel.minimum <= value <= channel.maximum):  # also rejects NaN
                signal = spec.signals[len(payload) - 1]
                raise CodecError(_range_message(spec, signal, channel, value, tick))
            payload.append(float(value))
        return payload

    def head(self, name: str) -> tuple[int, bool, bool, bool, int]:
        """What the wire times of message ``name``'s frames but their payload: id, extended, FD and
        BRS flags, length (``cosim.run.arbitration.bits_of_payloads``)."""
        spec = self.specs[name]
        classic = spec.role in (SYNC, NMT, HEARTBEAT)  # the protocol's frames are classic (``_classic``)
        fd = self.fd and not classic
        return spec.frame_id, False, fd, fd, self._packers[name].length

    def _frame(self, spec: MessageSpec, data: bytes) -> can.Message:
        return can.Message(
            arbitration_id=spec.frame_id, data=data, is_extended_id=False, is_fd=self.fd, bitrate_switch=self.fd
        )

    def with_full_tick(self, decoded: Decoded, near: int) -> Decoded:
        """A decoded heartbeat with the tick it closes in full (it carries it mod 2¹⁶: the tick
        nearest ``near`` with those bits); any other frame as it is."""
        found = self.control_macs.get(decoded.spec.frame_id)
        if found is None or found[1].tick is None or found[1].tick[1] >= 4:
            return decoded
        return Decoded(decoded.spec, nearest_tick(decoded.tick, near, 8 * found[1].tick[1]), decoded.values)

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


def ranges(specs: Sequence[MessageSpec]) -> tuple[np.ndarray, np.ndarray]:
    """The ranges of the messages' signals, each message's in turn: (minima, maxima) arrays."""
    channels = [c for spec in specs for c in spec.channels]
    return np.array([c.minimum for c in channels]), np.array([c.maximum for c in channels])


def saturated(values: Sequence[float], channels: Sequence[Channel]) -> list[float]:
    """Each value at the bound of its channel's range it crossed (±inf included; NaN stays NaN, which
    ``encode`` refuses): what a node's signal sends for a value outside its range."""
    return [min(max(v, c.minimum), c.maximum) if v == v else v for v, c in zip(values, channels)]


@functools.lru_cache(maxsize=16)
def _codec_of(text: str) -> Codec:
    """``Codec.from_dbc``'s codecs, by text (a CodecError is not kept: the text is read again)."""
    return Codec._parse(text)


def nearest_tick(counter: int, near: int, bits: int) -> int:
    """The tick with the ``bits`` low bits ``counter`` nearest to ``near`` (within half the modulus)."""
    half = 1 << (bits - 1)
    return near + ((counter - near + half) % (1 << bits)) - half


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
