"""What a run writes into its MCAP log: topics, their JSON Schemas, and the run's metadata.

Topics (``log_time`` is simulated time in ns; every message also carries ``tick`` and ``t`` [s]):

- ``/can/frames``: every frame on the bus in bus order: ``seq`` (position on the bus), ``id``,
  ``extended``, ``fd``, ``brs``, ``dlc`` (the data length code), ``length`` (payload bytes),
  ``data`` (hex), ``sender`` (the DBC
  node that transmits this id, ``unknown`` for ids outside the DBC), ``message`` (DBC name).
- ``/can/<MessageName>``: the decoded physical signals of each DBC message, named as in the DBC
  (the integer fields of NMT, SYNC and heartbeats).
- ``/truth/state``: the simulator's state, one field per state component.
- ``/truth/sensors``: the true (fault-free, noise-free) sensor readings.
- ``/truth/inputs``: ``commanded`` and ``effective`` (after actuator faults) inputs per actuator.
- ``/truth/faults``: what the fault layer applied: ``noise`` and ``fault`` (additive parts, per
  sensor), ``measured`` (what went on the bus; null where the frame was not sent), ``dropped``
  (sensors whose frame was not sent), ``effectiveness`` (δ per actuator) and ``active`` (labels
  of the active faults).
- ``/truth/bus_faults``: with bus faults only, what each did to a frame: ``label``, ``kind``,
  ``message``, ``event`` (lost, delayed, corrupted, bus_off, recovered, injected), ``errors``
  (error frames, or the TEC at bus-off), ``delay`` (s).
- ``/cosim/events``: runner events (start, stop, warnings, errors).
- ``/cosim/deadline_misses``: in realtime mode, each tick a node did not answer by its deadline.
- ``/cosim/wire``: with ``[bus] timing = "arbitrated"`` only, each frame's passage on the simulated
  wire, logged at its delivery: ``id``, ``message``, ``sender``, ``queued``, ``start``,
  ``delivered`` (s), ``latency`` (s), ``late`` (delivered after its deadline), ``bits`` and
  ``dropped`` (why it never went out, or null).

Metadata records: ``cosim.run`` (scenario name, seed, timing, plant, names, estimators and their
messages, fault onset, bus), ``cosim.scenario`` (the TOML as given and the validated scenario
as JSON), ``cosim.versions``, and at the end ``cosim.result`` (status, ticks, frame counts).
Attachments: the MJCF model and the DBC.
"""

from __future__ import annotations

from typing import Any

import can
import numpy as np
from can.util import len2dlc

from cosim.bus.codec import CLASSIC_TICK_BITS, CLIENT, COMMAND, ESTIMATE, NMT, SENSOR, Codec, Decoded
from cosim.bus.secoc import REASONS
from cosim.log.writer import McapLog, number, object_schema

FRAMES = "/can/frames"
STATE, SENSORS, INPUTS, FAULTS = "/truth/state", "/truth/sensors", "/truth/inputs", "/truth/faults"
EVENTS, DEADLINE_MISSES, FOREIGN = "/cosim/events", "/cosim/deadline_misses", "/cosim/foreign"
WIRE = "/cosim/wire"
SECURITY = "/cosim/security"
IDS = "/cosim/ids"
#: The key-less intrusion detector's checks (``cosim.run.detector``), as its verdicts on IDS name them.
IDS_CHECKS = ("period", "sequence", "range", "unknown")
BUS_FAULTS = "/truth/bus_faults"

_TICK = {"type": "integer", "description": "tick counter k of the runner"}
_TIME = number("simulated time t_k = k τ", "s")


def _named(names: tuple[str, ...], units: dict[str, str], description: str, nullable: bool = False) -> dict[str, Any]:
    return {
        "type": "object",
        "description": description,
        "properties": {n: number(n, units.get(n, ""), nullable) for n in names},
    }


def message_topic(name: str) -> str:
    return f"/can/{name}"


def carried_tick(logged_tick: int, counter: int) -> int:
    """The tick a decoded frame belongs to: its counter (k mod 2¹⁶ in classic CAN, k in CAN FD)
    unwrapped against the tick at which it was logged, which is never earlier (a late frame, in
    realtime mode, is logged at a later tick; fewer than 2¹⁶ ticks late is assumed)."""
    return logged_tick - (logged_tick - int(counter)) % (1 << CLASSIC_TICK_BITS)


class RunRecorder:
    """Writes one run's frames, truth and events into a McapLog."""

    def __init__(
        self,
        log: McapLog,
        codec: Codec,
        *,
        states: tuple[str, ...],
        sensors: tuple[str, ...],
        actuators: tuple[str, ...],
        units: dict[str, dict[str, str]],
        disturbances: tuple[str, ...] = (),
    ) -> None:
        self.log = log
        self.codec = codec
        self.states, self.sensors, self.actuators = states, sensors, actuators
        self.disturbances = disturbances
        self.frames = 0
        self._wire: int | None = None
        self._security: int | None = None
        self._ids: int | None = None
        self._bus_faults: int | None = None
        self._frames = log.channel(
            FRAMES,
            object_schema(
                "cosim.CanFrame",
                {
                    "tick": _TICK,
                    "t": _TIME,
                    "seq": {"type": "integer", "description": "position of the frame on the bus in this run"},
                    "id": {"type": "integer", "description": "arbitration id"},
                    "extended": {"type": "boolean", "description": "29-bit identifier"},
                    "fd": {"type": "boolean", "description": "CAN FD frame"},
                    "brs": {"type": "boolean", "description": "CAN FD bit rate switch"},
                    "dlc": {
                        "type": "integer",
                        "description": "data length code (0-8; 9-15 code 12-64 bytes in CAN FD)",
                    },
                    "length": {"type": "integer", "description": "payload length in bytes"},
                    "data": {"type": "string", "description": "payload, hex"},
                    "sender": {"type": "string", "description": "transmitting node (from the DBC)"},
                    "message": {"type": ["string", "null"], "description": "DBC message name"},
                },
                "A frame on the run's CAN bus",
            ),
        )
        self._decoded: dict[str, int] = {}
        for spec in codec.specs.values():
            if spec.channels or spec.role in (ESTIMATE, CLIENT, SENSOR, COMMAND):
                properties = {"tick": {"type": "integer", "description": "tick counter signal as carried by the frame"}}
                for channel, signal in zip(spec.channels, spec.signals):
                    properties[signal] = number(channel.description, channel.unit)
            else:  # NMT, SYNC and heartbeats: integer fields
                properties = {name: {"type": "integer"} for name in spec.signals}
            self._decoded[spec.name] = log.channel(
                message_topic(spec.name),
                object_schema(f"cosim.{spec.name}", properties, f"Decoded signals of {spec.name}"),
            )
        self._state = log.channel(
            STATE,
            object_schema(
                "cosim.TruthState",
                {"tick": _TICK, "t": _TIME, **{n: number(n, units["states"].get(n, "")) for n in states}},
                "State of the simulated plant",
            ),
        )
        self._sensors = log.channel(
            SENSORS,
            object_schema(
                "cosim.TruthSensors",
                {"tick": _TICK, "t": _TIME, **{n: number(n, units["sensors"].get(n, "")) for n in sensors}},
                "True (fault-free, noise-free) sensor readings",
            ),
        )
        self._inputs = log.channel(
            INPUTS,
            object_schema(
                "cosim.TruthInputs",
                {
                    "tick": _TICK,
                    "t": _TIME,
                    "commanded": _named(actuators, units["actuators"], "commanded input per actuator"),
                    "effective": _named(
                        actuators, units["actuators"], "input acting on the plant after actuator faults"
                    ),
                    "disturbance": _named(
                        disturbances,
                        units.get("disturbances", {}),
                        "unknown input acting on the plant (not on the bus)",
                    ),
                },
                "Actuator inputs and unknown inputs",
            ),
        )
        self._faults = log.channel(
            FAULTS,
            object_schema(
                "cosim.TruthFaults",
                {
                    "tick": _TICK,
                    "t": _TIME,
                    "noise": _named(sensors, units["sensors"], "measurement noise added per sensor"),
                    "fault": _named(sensors, units["sensors"], "deviation added by faults per sensor", nullable=True),
                    "measured": _named(
                        sensors, units["sensors"], "reading sent on the bus (null: not sent)", nullable=True
                    ),
                    "dropped": {
                        "type": "array",
                        "items": {"type": "string"},
                        "description": "sensors whose frame was not sent",
                    },
                    "effectiveness": _named(actuators, {}, "actuator effectiveness factor δ"),
                    "active": {
                        "type": "array",
                        "items": {"type": "string"},
                        "description": "labels of the active faults",
                    },
                },
                "Faults and noise applied by the fault layer",
            ),
        )
        self._misses = log.channel(
            DEADLINE_MISSES,
            object_schema(
                "cosim.DeadlineMiss",
                {
                    "tick": _TICK,
                    "t": _TIME,
                    "node": {
                        "type": "string",
                        "description": "the node whose heartbeat for this tick was not in by its deadline",
                    },
                    "count": {"type": "integer", "description": "deadline misses so far in the run"},
                },
                "Realtime mode: ticks a node did not answer in time",
            ),
        )
        self._foreign = log.channel(
            FOREIGN,
            object_schema(
                "cosim.Foreign",
                {
                    "tick": _TICK,
                    "t": _TIME,
                    "kind": {
                        "type": "string",
                        "enum": ["datagram", "frame"],
                        "description": "a datagram that is no frame of the run, or a frame the run did not send",
                    },
                    "reason": {"type": "string", "description": "why it does not belong"},
                    "source": {"type": "string", "description": "where it came from, where known"},
                    "id": {"type": ["integer", "null"], "description": "arbitration id (frames)"},
                    "length": {"type": "integer", "description": "bytes received (datagram) or payload bytes (frame)"},
                    "data": {"type": "string", "description": "the first bytes, hex"},
                    "count": {
                        "type": "integer",
                        "description": "how many such arrived in this tick that this record stands for",
                    },
                },
                "What arrived on the run's bus and does not belong to it: counted, never used",
            ),
        )
        self._events = log.channel(
            EVENTS,
            object_schema(
                "cosim.Event",
                {
                    "tick": _TICK,
                    "t": _TIME,
                    "level": {"type": "string", "enum": ["info", "warning", "error"]},
                    "event": {"type": "string"},
                    "detail": {"type": "string"},
                    "count": {"type": "integer", "description": "how many (frames lost, deadlines missed, ...)"},
                },
                "Runner events",
            ),
        )

    def frame(
        self, tick: int, t: float, t_ns: int, frame: can.Message, decoded: Decoded | None, sender: str = "unknown"
    ) -> None:
        """One frame on the bus; ``sender``: who sent a frame outside the DBC, where the run knows it."""
        spec = decoded.spec if decoded is not None else None
        self.log.write(
            self._frames,
            t_ns,
            {
                "tick": tick,
                "t": t,
                "seq": self.frames,
                "id": frame.arbitration_id,
                "extended": frame.is_extended_id,
                "fd": frame.is_fd,
                "brs": frame.bitrate_switch,
                "dlc": len2dlc(len(frame.data)),
                "length": len(frame.data),
                "data": bytes(frame.data).hex(),
                "sender": spec.sender if spec else sender,
                "message": spec.name if spec else None,
            },
        )
        self.frames += 1
        if decoded is not None:
            payload = decoded.values if decoded.spec.role == NMT else {"tick": decoded.tick, **decoded.values}
            self.log.write(self._decoded[decoded.spec.name], t_ns, payload)

    def truth(
        self,
        tick: int,
        t: float,
        t_ns: int,
        *,
        x: np.ndarray,
        y_true: np.ndarray,
        noise: np.ndarray,
        fault: np.ndarray,
        measured: np.ndarray,
        active: tuple[str, ...],
        u_cmd: np.ndarray,
        u_eff: np.ndarray,
        delta: np.ndarray,
        disturbance: np.ndarray | None = None,
    ) -> None:
        log = self.log
        log.write(self._state, t_ns, {"tick": tick, "t": t, **dict(zip(self.states, x.tolist()))})
        log.write(self._sensors, t_ns, {"tick": tick, "t": t, **dict(zip(self.sensors, y_true.tolist()))})
        log.write(
            self._inputs,
            t_ns,
            {
                "tick": tick,
                "t": t,
                "commanded": dict(zip(self.actuators, u_cmd.tolist())),
                "effective": dict(zip(self.actuators, u_eff.tolist())),
                "disturbance": dict(zip(self.disturbances, [] if disturbance is None else disturbance.tolist())),
            },
        )
        log.write(
            self._faults,
            t_ns,
            {
                "tick": tick,
                "t": t,
                "noise": dict(zip(self.sensors, noise.tolist())),
                "fault": dict(zip(self.sensors, fault.tolist())),
                "measured": dict(zip(self.sensors, measured.tolist())),
                "dropped": [name for name, value in zip(self.sensors, measured) if value != value],
                "effectiveness": dict(zip(self.actuators, delta.tolist())),
                "active": list(active),
            },
        )

    def foreign(
        self,
        tick: int,
        t: float,
        t_ns: int,
        kind: str,
        reason: str,
        source: str,
        length: int,
        data: bytes,
        frame_id: int | None = None,
        count: int = 1,
    ) -> None:
        self.log.write(
            self._foreign,
            t_ns,
            {
                "tick": tick,
                "t": t,
                "kind": kind,
                "reason": reason,
                "source": source,
                "id": frame_id,
                "length": length,
                "data": data.hex(),
                "count": count,
            },
        )

    def bus_fault(self, tick: int, t: float, t_ns: int, event: dict[str, Any]) -> None:
        """What a bus fault did (``cosim.run.busfaults.BusEvent``'s fields)."""
        if self._bus_faults is None:  # created with the first event: a run without bus faults has no such topic
            self._bus_faults = self.log.channel(
                BUS_FAULTS,
                object_schema(
                    "cosim.BusFaultEvent",
                    {
                        "tick": _TICK,
                        "t": _TIME,
                        "label": {"type": "string", "description": "the fault's label"},
                        "kind": {"type": "string", "description": "the fault's kind"},
                        "message": {"type": "string", "description": "the message (or node) it hit"},
                        "event": {
                            "type": "string",
                            "enum": ["lost", "delayed", "corrupted", "bus_off", "recovered", "injected"],
                        },
                        "errors": {"type": "integer", "description": "error frames (corrupted), TEC (bus_off)"},
                        "delay": number("how long the frame was held back", "s"),
                    },
                    "What a bus fault did to a frame",
                ),
            )
        self.log.write(self._bus_faults, t_ns, {"tick": tick, "t": t, **event})

    def wire(
        self,
        tick: int,
        t_ns: int,
        frame_id: int,
        message: str | None,
        sender: str,
        times_ns: tuple[int, int, int],
        late: bool,
        bits: int,
        dropped: str | None,
    ) -> None:
        """A frame's passage on the simulated wire: (queued, start, delivered) in ns."""
        if self._wire is None:  # created with the first passage: a log of an ideal bus has no such topic
            self._wire = self.log.channel(
                WIRE,
                object_schema(
                    "cosim.WirePassage",
                    {
                        "tick": _TICK,
                        "t": _TIME,
                        "id": {"type": "integer", "description": "arbitration id"},
                        "message": {"type": ["string", "null"], "description": "DBC message name"},
                        "sender": {"type": "string", "description": "the node that queued it"},
                        "queued": number("when its sender queued it", "s"),
                        "start": number("its start of frame on the wire", "s"),
                        "delivered": number("when its last bit was on the wire", "s"),
                        "latency": number("delivered − queued", "s"),
                        "late": {"type": "boolean", "description": "delivered after its deadline"},
                        "bits": {"type": "integer", "description": "its length on the wire, stuff bits included"},
                        "dropped": {"type": ["string", "null"], "description": "why it never went out"},
                    },
                    "A frame's passage on the simulated wire (arbitrated timing)",
                ),
            )
        queued, start, delivered = times_ns
        self.log.write(
            self._wire,
            t_ns,
            {
                "tick": tick,
                "t": t_ns / 1e9,
                "id": frame_id,
                "message": message,
                "sender": sender,
                "queued": queued / 1e9,
                "start": start / 1e9,
                "delivered": delivered / 1e9,
                "latency": (delivered - queued) / 1e9,
                "late": late,
                "bits": bits,
                "dropped": dropped,
            },
        )

    def deadline_miss(self, tick: int, t: float, t_ns: int, node: str, count: int) -> None:
        self.log.write(self._misses, t_ns, {"tick": tick, "t": t, "node": node, "count": count})

    def event(
        self, tick: int, t: float, t_ns: int, event: str, detail: str = "", level: str = "info", count: int = 0
    ) -> None:
        self.log.write(
            self._events, t_ns, {"tick": tick, "t": t, "level": level, "event": event, "detail": detail, "count": count}
        )

    def security(
        self,
        tick: int,
        t: float,
        t_ns: int,
        frame_id: int,
        message: str | None,
        sender: str,
        reason: str,
        fv: int,
        data: bytes,
    ) -> None:
        """A frame a receiver dropped because it failed SecOC verification (``cosim.bus.secoc``)."""
        if self._security is None:  # created with the first rejection: a log without one has no such topic
            self._security = self.log.channel(
                SECURITY,
                object_schema(
                    "cosim.SecurityRejection",
                    {
                        "tick": _TICK,
                        "t": _TIME,
                        "id": {"type": "integer", "description": "arbitration id"},
                        "message": {"type": ["string", "null"], "description": "DBC message name"},
                        "sender": {
                            "type": "string",
                            "description": "the sender it claims to come from (the id's owner)",
                        },
                        "reason": {
                            "type": "string",
                            "enum": list(REASONS),
                            "description": "bad_mac: the MAC does not match; replayed: freshness not newer than the "
                            "last accepted; stale: older than the acceptance window",
                        },
                        "freshness": {"type": "integer", "description": "the full freshness value as rebuilt"},
                        "data": {"type": "string", "description": "its payload (hex): a replay skips this frame"},
                    },
                    "A frame dropped by SecOC verification",
                ),
            )
        self.log.write(
            self._security,
            t_ns,
            {
                "tick": tick,
                "t": t,
                "id": frame_id,
                "message": message,
                "sender": sender,
                "reason": reason,
                "freshness": fv,
                "data": data.hex(),
            },
        )

    def ids(self, tick: int, t: float, t_ns: int, checks: dict[str, int], ids: list[int]) -> None:
        """The intrusion detector's verdict on one tick (``cosim.run.detector``)."""
        if self._ids is None:  # created with the first verdict: a run without the detector has no such topic
            self._ids = self.log.channel(
                IDS,
                object_schema(
                    "cosim.IntrusionVerdict",
                    {
                        "tick": _TICK,
                        "t": _TIME,
                        "alarm": {"type": "boolean", "description": "any check raised in this tick"},
                        **{
                            check: {"type": "integer", "description": f"ids the {check} check raised on"}
                            for check in IDS_CHECKS
                        },
                        "ids": {"type": "array", "items": {"type": "integer"}, "description": "those ids"},
                    },
                    "The key-less intrusion detector's verdict on a tick: period, sequence, range, unknown sender",
                ),
            )
        self.log.write(self._ids, t_ns, {"tick": tick, "t": t, "alarm": any(checks.values()), **checks, "ids": ids})
