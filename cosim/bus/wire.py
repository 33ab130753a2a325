"""A simulated CAN wire: frames queued by their senders go out one at a time, lowest id first.

The model is the one CAN's arbitration implies and what CANoe's simulated buses do:

- a frame occupies the wire for its exact length (``cosim.bus.timing.frame_bits``: stuff bits
  counted, the 3-bit intermission included) at the nominal bit rate, and, for a CAN FD frame with
  BRS, its data phase at the data bit rate;
- when the wire falls idle, every frame queued by then contends and the lowest arbitration id
  wins (bitwise arbitration: a dominant 0 overwrites a recessive 1); a frame on the wire is never
  preempted, so a high-priority frame queued while a long one is on the wire waits for it;
- a frame is delivered to every receiver when its last bit (the end of EOF) is on the wire, three
  bit times before the wire is idle again (the intermission);
- a sender holds one frame per id, as a CAN controller's transmit object does: a newer frame of an
  id whose older one has not won arbitration yet replaces it (AUTOSAR CanIf's transmit
  cancellation), so an overloaded bus loses stale frames rather than queueing without bound.

Times are integer nanoseconds, a frame's duration rounded once (exact at the usual bit rates:
125 kbit/s is 8000 ns a bit), so a schedule is the same on every machine.

``Wire`` is pure bookkeeping: nothing here sends anything. ``cosim.run.arbitration`` decides,
from its schedule, which frames the run's receivers get in which tick.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from can.util import len2dlc

from cosim.bus.timing import frame_bits

_INTERMISSION = 3  # bits after EOF before the next SOF: part of a frame's length, not of its delivery


@dataclass(eq=False)  # a frame is itself, whatever it carries: the queue finds and removes it by identity
class WireFrame:
    """A frame offered to the wire by ``sender`` at ``queued_ns``; ``deadline_ns``: when it is late.

    ``payload`` is whatever the caller needs back with the transmission (the python-can message
    and its decoding); the wire looks only at the fields before it."""

    frame_id: int
    extended: bool
    fd: bool
    brs: bool
    data: bytes
    sender: str
    queued_ns: int
    deadline_ns: int
    payload: Any = None
    seq: int = field(default=0, compare=False)
    bits: tuple[int, int] | None = field(default=None, compare=False, repr=False)
    """``bits_of`` the frame, once it has been asked."""


@dataclass(frozen=True)
class Transmission:
    """One frame's passage: on the wire from ``start_ns``, delivered at ``delivered_ns``, the wire
    idle again at ``end_ns``; ``dropped``: why it never went out (then all three are its drop time)."""

    frame: WireFrame
    start_ns: int
    delivered_ns: int
    end_ns: int
    dropped: str | None = None

    @property
    def latency_ns(self) -> int:
        return self.delivered_ns - self.frame.queued_ns

    @property
    def late(self) -> bool:
        return self.dropped is None and self.delivered_ns > self.frame.deadline_ns


_DLC = tuple(int(len2dlc(length)) for length in range(65))  # a look-up: python-can's function costs µs per frame


def dlc_of(length: int) -> int:
    """The data length code of a payload of ``length`` bytes (CAN FD lengths above 8)."""
    return _DLC[length] if length < len(_DLC) else _DLC[-1]  # as len2dlc: 15 for anything longer


def bits_of(frame: WireFrame) -> tuple[int, int]:
    """(nominal, data-rate) bits of ``frame`` on the wire, stuff bits and intermission included."""
    if frame.bits is None:
        frame.bits = frame_bits(
            frame.frame_id, frame.extended, frame.fd, frame.brs, dlc_of(len(frame.data)), frame.data
        )
    return frame.bits


class Wire:
    """The wire at ``bitrate`` (and ``data_bitrate`` for CAN FD data phases with BRS)."""

    def __init__(self, bitrate: int, data_bitrate: int | None = None) -> None:
        self.bitrate = bitrate
        self.data_bitrate = data_bitrate or bitrate
        self.idle_ns = 0  # the wire carries nothing from here on (as far as it was simulated)
        self.queue: list[WireFrame] = []
        self._seq = 0

    def duration_ns(self, frame: WireFrame) -> tuple[int, int]:
        """(ns on the wire, ns from SOF to delivery) of ``frame``."""
        nominal, fast = bits_of(frame)
        total = round(nominal * 1e9 / self.bitrate + fast * 1e9 / self.data_bitrate)
        return total, total - round(_INTERMISSION * 1e9 / self.bitrate)

    def offer(self, frame: WireFrame) -> None:
        """Queue a frame; it contends from its ``queued_ns`` on."""
        frame.seq = self._seq
        self._seq += 1
        self.queue.append(frame)

    def run(self, stop_ns: int) -> list[Transmission]:
        """Simulate the wire: the transmissions that start before ``stop_ns`` (in order), and the
        frames replaced before they could go, are taken off the queue and returned."""
        out: list[Transmission] = []
        t = self.idle_ns
        while self.queue:
            eligible = [f for f in self.queue if f.queued_ns <= t]
            if not eligible:
                t = max(t, min(f.queued_ns for f in self.queue))
                if t >= stop_ns:
                    break
                continue
            if t >= stop_ns:
                break
            dropped = self._replace_stale(eligible)
            if dropped:
                out += dropped
                eligible = [f for f in self.queue if f.queued_ns <= t]
            winner = min(eligible, key=lambda f: (f.frame_id, f.queued_ns, f.seq))
            self.queue.remove(winner)
            total, delivery = self.duration_ns(winner)
            out.append(Transmission(winner, t, t + delivery, t + total))
            t += total
            self.idle_ns = t
        return out

    def _replace_stale(self, eligible: list[WireFrame]) -> list[Transmission]:
        """A sender's newer frame of an id replaces its older one still waiting."""
        if len({(frame.sender, frame.frame_id) for frame in eligible}) == len(eligible):
            return []  # the usual case: one frame per sender and id
        newest: dict[tuple[str, int], WireFrame] = {}
        for frame in sorted(eligible, key=lambda f: (f.queued_ns, f.seq)):
            newest[(frame.sender, frame.frame_id)] = frame
        dropped = []
        for frame in eligible:
            newer = newest[(frame.sender, frame.frame_id)]
            if newer is not frame:
                self.queue.remove(frame)
                at = newer.queued_ns
                dropped.append(Transmission(frame, at, at, at, "replaced by a newer frame of its id"))
        return dropped

    def fork(self) -> Wire:
        """A copy to plan on: the same clock and queue (the same frames); what it runs and is offered
        leaves this wire as it was."""
        trial = Wire(self.bitrate, self.data_bitrate)
        trial.idle_ns, trial.queue, trial._seq = self.idle_ns, list(self.queue), self._seq
        return trial

    def commit(self, planned: list[Transmission], stop_ns: int) -> list[Transmission]:
        """What ``run(stop_ns)`` would return and leave, taken from ``planned``: what a ``fork`` of
        this wire ran to a later stop after being offered the frames this wire has been offered
        since (the same objects, in the same order). The wire is deterministic, so its passages up
        to ``stop_ns`` are a prefix of the fork's: every passage up to the last one that starts
        before ``stop_ns`` (a replaced frame goes in the loop of the winner that follows it)."""
        end = 0
        for i, passage in enumerate(planned):
            if passage.dropped is None:
                if passage.start_ns >= stop_ns:
                    break
                end = i + 1
        taken = planned[:end]
        if taken:
            gone = {id(passage.frame) for passage in taken}
            self.queue = [frame for frame in self.queue if id(frame) not in gone]
            self.idle_ns = taken[-1].end_ns  # the last one taken is a passage, not a replaced frame
        return taken

    def drain(self) -> list[Transmission]:
        """Everything still queued, to the last frame (the end of a run)."""
        return self.run(2**62)
