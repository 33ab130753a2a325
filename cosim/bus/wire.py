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

import heapq
from dataclasses import dataclass, field
from typing import Any

import numpy as np
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
    durations: tuple[int, int, int, int] | None = field(default=None, compare=False, repr=False)
    """(bit rate, data bit rate, ``Wire.duration_ns``) of the frame on the last wire that asked: a
    frame that waits is planned at every tick until it goes."""


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


def _queue_order(frame: WireFrame) -> tuple[int, int]:
    """When a frame contends from, then the order it was offered in: a sender's newest frame of an id is last."""
    return frame.queued_ns, frame.seq


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
        known = frame.durations
        if known is None or known[0] != self.bitrate or known[1] != self.data_bitrate:
            nominal, fast = bits_of(frame)
            total = round(nominal * 1e9 / self.bitrate + fast * 1e9 / self.data_bitrate)
            known = frame.durations = (
                self.bitrate,
                self.data_bitrate,
                total,
                total - round(_INTERMISSION * 1e9 / self.bitrate),
            )
        return known[2], known[3]

    def durations_rows(self, nominal: np.ndarray, fast: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``duration_ns`` of frames of ``nominal`` and ``fast`` bits (arrays), the same integers:
        (ns on the wire, ns from SOF to delivery)."""
        total = np.rint(nominal * 1e9 / self.bitrate + fast * 1e9 / self.data_bitrate).astype(np.int64)
        return total, total - round(_INTERMISSION * 1e9 / self.bitrate)

    def offer(self, frame: WireFrame) -> None:
        """Queue a frame; it contends from its ``queued_ns`` on."""
        frame.seq = self._seq
        self._seq += 1
        self.queue.append(frame)

    def run(self, stop_ns: int) -> list[Transmission]:
        """Simulate the wire: the transmissions that start before ``stop_ns`` (in order), and the
        frames replaced before they could go, are taken off the queue and returned.

        Whenever the wire is idle at t, the frames queued by t contend: first a sender's older
        frames of an id are replaced by its newest one queued by t (the replaced ones in the order
        they were offered, each at the time its replacement was queued), then the lowest (id,
        queue time, offer) wins and holds the wire for its duration. Frames join the contest in
        the order of their queue times and the contenders are a heap: n frames cost O(n log n)."""
        out: list[Transmission] = []
        if not self.queue:
            return out
        t = self.idle_ns
        waiting = sorted(self.queue, key=_queue_order)
        n, i = len(waiting), 0
        contenders: list[tuple[int, int, int, int, WireFrame]] = []  # a heap, by (id, queue time, offer)
        holding: dict[tuple[str, int], WireFrame] = {}  # (sender, id) -> its frame contending
        gone: set[int] = set()  # the frames taken off the queue (sent or replaced), by id()
        push, pop, duration = heapq.heappush, heapq.heappop, self.duration_ns
        while True:
            if not holding and (i == n or waiting[i].queued_ns > t):  # nothing queued by t
                if i == n:
                    break
                t = max(t, waiting[i].queued_ns)
                if t >= stop_ns:
                    break
                continue
            if t >= stop_ns:
                break
            replaced: list[tuple[WireFrame, tuple[str, int]]] | None = None
            while i < n and waiting[i].queued_ns <= t:  # the frames queued by t join
                frame = waiting[i]
                key = (frame.sender, frame.frame_id)
                held = holding.get(key)
                if held is not None:  # the sender's older frame of this id (frames join in queue order)
                    replaced = replaced or []
                    replaced.append((held, key))
                    gone.add(id(held))
                holding[key] = frame
                push(contenders, (frame.frame_id, frame.queued_ns, frame.seq, i, frame))
                i += 1
            if replaced:
                for older, key in sorted(replaced, key=lambda item: item[0].seq):
                    at = holding[key].queued_ns
                    out.append(Transmission(older, at, at, at, "replaced by a newer frame of its id"))
            winner = pop(contenders)[-1]
            while id(winner) in gone:  # replaced while it waited in the heap
                winner = pop(contenders)[-1]
            gone.add(id(winner))
            del holding[(winner.sender, winner.frame_id)]
            total, delivery = duration(winner)
            out.append(Transmission(winner, t, t + delivery, t + total))
            t += total
            self.idle_ns = t
        if gone:
            self.queue = [frame for frame in self.queue if id(frame) not in gone]
        return out

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
