"""What a run writes into its MCAP log: its topics (``cosim.log.topics``: names, schemas, records),
channel by channel, in the order a reader finds them.

The channels of every run are registered up front: ``/can/frames``, the decoded ``/can/<Message>``
of each DBC message, the truth (``/truth/state``, ``sensors``, ``inputs``, ``faults``),
``/cosim/deadline_misses``, ``/cosim/foreign`` and ``/cosim/events``. ``/truth/bus_faults``,
``/cosim/wire``, ``/cosim/security``, ``/cosim/ids`` and ``/plant/fmu`` are registered with their
first message: a run without bus faults, an arbitrated wire, SecOC rejections, the intrusion
detector or an FMU plant that says something has no such topic. The run's metadata records are ``cosim.log.metadata``'s.
"""

from __future__ import annotations

from typing import Any

import can
import numpy as np

from cosim.bus.codec import Codec, Decoded
from cosim.log.topics import (
    BUS_FAULTS,
    DEADLINE_MISSES,
    EVENTS,
    FAULTS,
    FOREIGN,
    FRAMES,
    IDS,
    IDS_CHECKS,
    INPUTS,
    SECURITY,
    SENSORS,
    STATE,
    WIRE,
    BusFaultEvent,
    CanFrame,
    DeadlineMiss,
    Event,
    FmuMessage,
    Foreign,
    IntrusionVerdict,
    PlantNames,
    Record,
    SecurityRejection,
    Signals,
    TruthFaults,
    TruthInputs,
    TruthSensors,
    TruthState,
    WirePassage,
    carried_tick,
    message_topic,
)
from cosim.log.writer import McapLog, SinkLog

# Readers that still import the topics' names from here (cosim.log.topics is their home).
__all__ = [
    "BUS_FAULTS",
    "DEADLINE_MISSES",
    "EVENTS",
    "FAULTS",
    "FOREIGN",
    "FRAMES",
    "IDS",
    "IDS_CHECKS",
    "INPUTS",
    "SECURITY",
    "SENSORS",
    "STATE",
    "WIRE",
    "RunRecorder",
    "carried_tick",
    "message_topic",
]


class RunRecorder:
    """Writes one run's frames, truth and events into a McapLog, each through its topic's record;
    or hands them to a ``SinkLog`` (a run that writes no file), which takes the ``/can/frames``
    records themselves and whose sink is told only the time of the messages it does not read
    (they are not built)."""

    def __init__(
        self,
        log: McapLog | SinkLog,
        codec: Codec,
        *,
        states: tuple[str, ...],
        sensors: tuple[str, ...],
        actuators: tuple[str, ...],
        units: dict[str, dict[str, str]],
        disturbances: tuple[str, ...] = (),
    ) -> None:
        self.log = log
        # a log without a file takes the records themselves, and only the time of what it does not read
        self._records = isinstance(log, SinkLog)
        self.codec = codec
        self.plant = PlantNames(states, sensors, actuators, disturbances, units)
        self.frames = 0
        self._frames = log.channel(FRAMES, CanFrame.schema())
        self._decoded = {
            spec.name: log.channel(message_topic(spec.name), Signals.schema(spec)) for spec in codec.specs.values()
        }
        self._state, self._sensors, self._inputs, self._faults, self._misses, self._foreign, self._events = (
            log.channel(record.TOPIC, record.schema(self.plant))
            for record in (TruthState, TruthSensors, TruthInputs, TruthFaults, DeadlineMiss, Foreign, Event)
        )
        self._later: dict[type[Record], int] = {}

    def _channel(self, record: type[Record]) -> int:
        """The channel of a topic registered with its first message."""
        channel = self._later.get(record)
        if channel is None:
            channel = self._later[record] = self.log.channel(record.TOPIC, record.schema())
        return channel

    def frame(
        self, tick: int, t: float, t_ns: int, frame: can.Message, decoded: Decoded | None, sender: str = "unknown"
    ) -> None:
        """One frame on the bus; ``sender``: who sent a frame outside the DBC, where the run knows it."""
        spec = decoded.spec if decoded is not None else None
        log, sender, message = self.log, spec.sender if spec else sender, spec.name if spec else None
        if not self._records:
            log.write(self._frames, t_ns, CanFrame.payload(tick, t, self.frames, frame, sender, message))
        elif log.reads(self._frames):
            log.write(self._frames, t_ns, CanFrame.of(tick, t, self.frames, frame, sender, message))
        else:
            log.seen(self._frames, t_ns)
        self.frames += 1
        if decoded is not None:
            channel = self._decoded[decoded.spec.name]
            if log.reads(channel):
                log.write(channel, t_ns, Signals.payload(decoded))
            else:
                log.seen(channel, t_ns)

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
        log, plant = self.log, self.plant
        if log.reads(self._state):
            log.write(self._state, t_ns, TruthState.payload(tick, t, plant.states, x))
        else:
            log.seen(self._state, t_ns)
        if log.reads(self._sensors):
            log.write(self._sensors, t_ns, TruthSensors.payload(tick, t, plant.sensors, y_true))
        else:
            log.seen(self._sensors, t_ns)
        if log.reads(self._inputs):
            log.write(self._inputs, t_ns, TruthInputs.payload(tick, t, plant, u_cmd, u_eff, disturbance))
        else:
            log.seen(self._inputs, t_ns)
        if log.reads(self._faults):
            log.write(self._faults, t_ns, TruthFaults.payload(tick, t, plant, noise, fault, measured, delta, active))
        else:
            log.seen(self._faults, t_ns)

    def foreign(self, t_ns: int, record: Foreign) -> None:
        """An arrival that does not belong to the run (``cosim.run.foreign_traffic`` makes the record)."""
        self.log.write(self._foreign, t_ns, record)

    def bus_fault(self, tick: int, t: float, t_ns: int, event: dict[str, Any]) -> None:
        """What a bus fault did (``cosim.run.busfaults.BusEvent``'s fields)."""
        self.log.write(self._channel(BusFaultEvent), t_ns, BusFaultEvent(tick=tick, t=t, **event))

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
        payload = WirePassage.payload(tick, t_ns, frame_id, message, sender, *times_ns, late, bits, dropped)
        self.log.write(self._channel(WirePassage), t_ns, payload)

    def deadline_miss(self, tick: int, t: float, t_ns: int, node: str, count: int) -> None:
        self.log.write(self._misses, t_ns, DeadlineMiss(tick=tick, t=t, node=node, count=count))

    def event(
        self, tick: int, t: float, t_ns: int, event: str, detail: str = "", level: str = "info", count: int = 0
    ) -> None:
        record = Event(tick=tick, t=t, level=level, event=event, detail=detail, count=count)
        self.log.write(self._events, t_ns, record)

    def fmu_messages(self, tick: int, t: float, t_ns: int, messages: list[Any]) -> None:
        """What an FMU plant logged or printed (``cosim.plant.fmu_calls.FmuMessage``s) by tick k."""
        channel = self._channel(FmuMessage)
        for m in messages:
            record = FmuMessage(tick=tick, t=t, source=m.source, status=m.status, category=m.category, message=m.text)
            self.log.write(channel, t_ns, record)

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
        record = SecurityRejection(
            tick=tick, t=t, id=frame_id, message=message, sender=sender, reason=reason, freshness=fv, data=data.hex()
        )
        self.log.write(self._channel(SecurityRejection), t_ns, record)

    def ids(self, tick: int, t: float, t_ns: int, checks: dict[str, int], ids: list[int]) -> None:
        """The intrusion detector's verdict on one tick (``cosim.run.detector``)."""
        self.log.write(self._channel(IntrusionVerdict), t_ns, IntrusionVerdict.payload(tick, t, checks, ids))
