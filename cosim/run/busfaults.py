"""Bus faults in the runner: what becomes of its frames on the way to the receivers, and the
frames of intruders.

The runner sends the plant's sensor frames (and the open-loop commands), so it is where a bus
fault can act on what the estimators receive, as CANstress acts on a real bus: each tick, every
data frame of a targeted message meets the active bus faults (``faults.models.BusFault``), each
drawing from its own seeded stream:

- ``frame_loss``: the frame never arrives; ``frame_delay``: it is queued ``delay`` ± ``jitter``
  later (on an ideal bus it arrives in the tick that delay reaches, late when that is a later
  one; on an arbitrated bus the wire decides);
- ``frame_corruption`` and ``bus_off``: transmission attempts are destroyed, each an error frame
  (counted) and 8 more on the transmitter's error counter (TEC; a success takes 1 off); CAN
  retransmits, and a node whose TEC passes 255 is bus-off: it sends nothing until it recovers
  after 128 × 11 recessive bits (``recover``), or for the rest of the run;
- ``spoofing`` and ``replay``: an intruder's frame of the message follows the genuine one (the
  runner encodes it for the current tick: nothing protects the counter of an unauthenticated
  frame); ``babbling_node``: periodic frames on the wire (arbitrated timing). With SecOC the
  spoofer has no key (its trailer is zeros) and the replaying intruder resends the secured frame
  it recorded byte for byte: it cannot sign another.

SYNC(k) announces the frames the receivers count in tick k: an intruder's frame of a message
whose genuine frame came too is a second copy, which a receiver does not count (it distrusts
both: ``cosim.bus.client.TickAssembler``); one whose genuine frame did not come counts. With SecOC
only the genuine ones count, since every receiver drops the intruders'. What each fault did goes to
``/truth/bus_faults``; intruders' frames are foreign frames (``/cosim/foreign``).
"""

from __future__ import annotations

import bisect
import math
import zlib
from dataclasses import dataclass, field

import can
import numpy as np

import faults as fm
from cosim.bus.codec import COMMAND, SENSOR, SYNC, Codec, Decoded
from cosim.errors import CodecError

Frame = tuple[can.Message, Decoded | None]
_BUS = 3  # spawn key group of the bus faults' random streams (noise 0, sensor faults 1, actuators 2)
_BUS_OFF_TEC = 255
_RECOVERY_BITS = 128 * 11


@dataclass(frozen=True)
class BusEvent:
    """One thing a bus fault did, for ``/truth/bus_faults``."""

    label: str
    kind: str
    message: str
    event: str  # lost, delayed, corrupted, bus_off, recovered, injected
    errors: int = 0
    delay: float = 0.0


@dataclass
class Applied:
    """A tick's frames after the bus faults: to send (SYNC first, re-announced), the wire delay of
    each delayed frame and the intruder of each injected one (both by ``id()`` of the frame)."""

    frames: list[Frame]
    delays_ns: dict[int, int] = field(default_factory=dict)
    intruders: dict[int, str] = field(default_factory=dict)
    events: list[BusEvent] = field(default_factory=list)


def counted_by_receivers(
    frames: list[Frame], intruders: dict[int, str], authenticated: bool, counter: int
) -> list[Frame]:
    """The frames of a tick its receivers count (``cosim.bus.client.TickAssembler``): under SecOC all
    but the intruders' (they fail it); else the sensor and command frames that carry the tick's
    ``counter`` (k modulo the codec's ``tick_modulus``), but for second copies of a message
    (receivers distrust both)."""
    if authenticated:
        return [frame for frame in frames if id(frame) not in intruders]
    seen: set[str] = set()
    kept = []
    for frame in frames:
        decoded = frame[1]
        if decoded is None or decoded.spec.role not in (SENSOR, COMMAND) or decoded.tick != counter:
            continue
        if decoded.spec.name not in seen:
            seen.add(decoded.spec.name)
            kept.append(frame)
    return kept


class BusFaultStage:
    """The scenario's bus faults between the runner and the receivers."""

    def __init__(
        self,
        codec: Codec,
        models: list[fm.BusFault],
        seed: int,
        dt_ns: int,
        bitrate: int,
        arbitrated: bool,
        authenticated: bool = False,
    ) -> None:
        self.codec, self.models, self.dt_ns, self.arbitrated = codec, models, dt_ns, arbitrated
        self.authenticated = authenticated
        self._recorded: dict[str, list[tuple[float, bytes]]] = {}  # SecOC: message -> (t, data) a replayer heard
        for model in models:
            model.reset(
                np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(_BUS, zlib.crc32(model.label.encode()))))
            )
        self.recovery_ns = round(_RECOVERY_BITS * 1e9 / bitrate)
        self.tec: dict[str, int] = {}
        self.off_until: dict[str, float] = {}  # node -> when it may rejoin (ns; inf: never)
        self.error_frames = 0
        self._held: list[tuple[int, Frame]] = []  # ideal bus: (tick it arrives in, frame) of delayed frames
        self.intruder_labels = {m.label for m in models if m.intruder}

    def active(self, t: float) -> list[str]:
        """Labels of the bus faults active at t (for /truth/faults)."""
        return [m.label for m in self.models if m.active(t)]

    def apply(self, k: int, frames: list[Frame]) -> Applied:
        t_ns = k * self.dt_ns
        t = t_ns / 1e9
        out = Applied([])
        sent: list[Frame] = []
        for frame in frames[1:]:
            if frame[1] is None:
                sent.append(frame)
            elif self._genuine(k, t_ns, frame, sent, out):
                self._inject(k, t, frame[1].spec.name, sent, out)
        self._inject(k, t, None, sent, out)  # intruders whose genuine frame did not come
        self._forge(t, sent, out)
        late = [frame for arrives, frame in self._held if arrives <= k]
        self._held = [(arrives, frame) for arrives, frame in self._held if arrives > k]
        sync, _ = frames[0]
        if frames[0][1] is not None and frames[0][1].spec.role == SYNC:
            counted = counted_by_receivers(sent, out.intruders, self.authenticated, k % self.codec.tick_modulus)
            sync = self.codec.sync(k, len(counted))
        out.frames = [(sync, self.codec.decode(sync)), *sent, *late]
        return out

    def _genuine(self, k: int, t_ns: int, frame: Frame, sent: list[Frame], out: Applied) -> bool:
        """One of the runner's frames through the active bus faults that hit it; True if it (or an
        intruder's frame in its place) went into ``sent``, for the intruders that follow it."""
        message, decoded = frame
        assert decoded is not None
        t = t_ns / 1e9
        name, sender = decoded.spec.name, decoded.spec.sender
        if self._off(sender, t_ns, out):
            out.events.append(BusEvent("", "bus_off", name, "lost"))
            return False
        fates = [(model, model.fate(name, t)) for model in self.models if model.active(t) and model.hits(name, sender)]
        for model, fate in fates:
            if fate.lost:
                out.events.append(BusEvent(model.label, model.kind, name, "lost"))
            if fate.delay:
                out.events.append(BusEvent(model.label, model.kind, name, "delayed", delay=fate.delay))
        errors = sum(fate.errors for _, fate in fates)
        culprit = next((model for model, fate in fates if fate.errors), None)
        single_shot = any(fate.single_shot for _, fate in fates)
        if errors and self._errors(sender, name, errors, single_shot, culprit, t_ns, out):
            return False
        if any(fate.lost for _, fate in fates):
            return self._substitute(k, t, decoded, sent, out)
        if not errors:
            self.tec[sender] = max(0, self.tec.get(sender, 0) - 1)
        self._observe(name, decoded, bytes(message.data), t)
        delay = sum(fate.delay for _, fate in fates)
        if delay > 0:
            delay_ns = round(delay * 1e9)
            if self.arbitrated:
                out.delays_ns[id(frame)] = delay_ns
            elif (arrives := (t_ns + delay_ns) // self.dt_ns) > k:
                self._held.append((arrives, frame))
                return False
        sent.append(frame)
        return True

    def _observe(self, name: str, decoded: Decoded, data: bytes, t: float) -> None:
        """A genuine frame that went out, as the intruders that record hear it."""
        for model in self.models:
            model.observe(name, tuple(decoded.values[s] for s in decoded.spec.signals), t)
            if self.authenticated and isinstance(model, fm.Replay) and model.message == name:
                heard = self._recorded.setdefault(name, [])
                heard.append((t, data))
                while heard[0][0] < t - model.lag - 1.0:
                    heard.pop(0)

    def _substitute(self, k: int, t: float, decoded: Decoded, sent: list[Frame], out: Applied) -> bool:
        """An intruder's frame in the slot of a genuine one that did not go out (a masquerade)."""
        values = tuple(decoded.values[s] for s in decoded.spec.signals)
        for model in self.models:
            if model.active(t) and (forged := model.substitute(decoded.spec.name, values, t)) is not None:
                self._intrude(model, self.codec.encode_decoded(decoded.spec.name, k, forged), sent, out)
                return True
        return False

    def _intrude(self, model: fm.BusFault, frame: Frame, sent: list[Frame], out: Applied) -> None:
        """An intruder's frame onto the bus (after those in ``sent``)."""
        sent.append(frame)
        out.intruders[id(frame)] = model.label
        name = frame[1].spec.name if frame[1] is not None else f"0x{frame[0].arbitration_id:03X}"
        out.events.append(BusEvent(model.label, model.kind, name, "injected"))

    def _forge(self, t: float, sent: list[Frame], out: Applied) -> None:
        """The raw frames intruders put on the bus in this tick (fuzzing): on an arbitrated bus each
        queued at its own time, on an ideal one in the tick."""
        dt = self.dt_ns / 1e9
        for model in self.models:
            if not (model.start < t + dt and t < model.end):  # its window meets the tick
                continue
            for when, frame_id, data in model.forge(t, dt):
                fd = self.codec.fd
                message = can.Message(
                    arbitration_id=frame_id, data=data, is_extended_id=False, is_fd=fd, bitrate_switch=fd
                )
                try:
                    frame: Frame = (message, self.codec.decode(message))
                except CodecError:  # on one of the run's ids, but not one of its frames (length, bits)
                    frame = (message, None)
                if self.arbitrated and (offset := round((when - t) * 1e9)) > 0:
                    out.delays_ns[id(frame)] = offset
                self._intrude(model, frame, sent, out)

    def _off(self, sender: str, t_ns: int, out: Applied) -> bool:
        """Whether ``sender`` is bus-off at t (after a recovery its counters start again at 0)."""
        until = self.off_until.get(sender)
        if until is None:
            return False
        if t_ns >= until:
            del self.off_until[sender]
            self.tec[sender] = 0
            out.events.append(BusEvent("", "bus_off", sender, "recovered"))
            return False
        return True

    def _errors(
        self,
        sender: str,
        name: str,
        errors: int,
        single_shot: bool,
        culprit: fm.BusFault | None,
        t_ns: int,
        out: Applied,
    ) -> bool:
        """Destroyed attempts of one frame; True if it never gets through (bus-off or single shot)."""
        tec = self.tec.get(sender, 0)
        attempts = min(errors, (_BUS_OFF_TEC - tec) // 8 + 1)  # the attempt that passes 255 is the last
        self.error_frames += attempts
        self.tec[sender] = tec + 8 * attempts
        label, kind = (culprit.label, culprit.kind) if culprit is not None else ("", "")
        out.events.append(BusEvent(label, kind, name, "corrupted", errors=attempts))
        if self.tec[sender] > _BUS_OFF_TEC:
            recover = not isinstance(culprit, fm.BusOff) or culprit.recover
            self.off_until[sender] = t_ns + self.recovery_ns if recover else math.inf
            out.events.append(BusEvent(label, "bus_off", sender, "bus_off", errors=self.tec[sender]))
            return True
        if single_shot:
            return True
        self.tec[sender] = max(0, self.tec[sender] - 1)
        return False

    def _inject(self, k: int, t: float, name: str | None, sent: list[Frame], out: Applied) -> None:
        """Intruders' frames of ``name``, right after the genuine one (None: those not sent yet)."""
        done = set(out.intruders.values())
        for model in self.models:
            if not model.intruder or not model.active(t) or model.label in done:
                continue
            if name is not None and name not in model.targets():
                continue
            for message, values in model.inject(t):
                if self.authenticated and isinstance(model, fm.Replay):
                    frame = self._recorded_frame(message, t - model.lag)
                    if frame is None:
                        continue
                else:
                    frame = self.codec.encode_decoded(message, k, values)
                self._intrude(model, frame, sent, out)

    def _recorded_frame(self, message: str, until: float) -> Frame | None:
        """The secured frame of ``message`` a replaying intruder recorded last by ``until``, as it was."""
        heard = self._recorded.get(message, [])
        last = bisect.bisect_right(heard, until + 1e-12, key=lambda entry: entry[0])  # heard in time order
        if not last:
            return None
        spec = self.codec.specs[message]
        frame = can.Message(
            arbitration_id=spec.frame_id, data=heard[last - 1][1], is_extended_id=False, is_fd=True, bitrate_switch=True
        )
        return frame, self.codec.decode(frame)
