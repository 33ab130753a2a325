"""What reaches the runner that does not belong to the run: datagrams that are no frame of it and
frames nobody in it sent (or an intruder's), counted, logged on /cosim/foreign (one record each,
up to ``RECORDS_PER_TICK`` a tick, the rest as counts at the tick's end), and named in the report of
a failure that follows them.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable

import can

from cosim.bus.codec import Codec
from cosim.bus.udp import ForeignDatagram
from cosim.log.recorder import RunRecorder
from cosim.log.topics import Foreign
from cosim.run.outcome import flood_report

RECORDS_PER_TICK = 64  # foreign arrivals logged one by one per tick; the rest as counts


class ForeignTraffic:
    """The run's foreign arrivals; ``tick()`` is the tick the runner is in, ``time(k)`` t_k in
    seconds and nanoseconds."""

    def __init__(
        self, recorder: RunRecorder, codec: Codec, tick: Callable[[], int], time: Callable[[int], tuple[float, int]]
    ) -> None:
        self.recorder, self.codec, self.tick, self.time = recorder, codec, tick, time
        self.counts = {"datagrams": 0, "frames": 0}
        self.last: str | None = None
        """The latest foreign frame, for the error that follows it."""
        self._this_tick = 0  # records written in the current tick (at most RECORDS_PER_TICK)
        self._more: Counter[tuple[str, str]] = Counter()  # (kind, reason) -> not written one by one

    def datagram(self, datagram: ForeignDatagram) -> None:
        self.counts["datagrams"] += 1
        self._record("datagram", datagram.reason, datagram.source, datagram.length, datagram.data)

    def frame(self, frame: can.Message, reason: str, seq: int | None = None, source: str = "") -> None:
        self.counts["frames"] += 1
        spec = self.codec.spec_of(frame)
        name = spec.name if spec is not None else f"0x{frame.arbitration_id:03X}"
        self.last = f"{name} (id 0x{frame.arbitration_id:03X}, data {bytes(frame.data).hex() or '-'})"
        self._record("frame", reason, source, len(frame.data), bytes(frame.data), frame.arbitration_id, seq)

    def _record(
        self,
        kind: str,
        reason: str,
        source: str,
        length: int,
        data: bytes,
        frame_id: int | None = None,
        seq: int | None = None,
    ) -> None:
        """Log it, one record each up to RECORDS_PER_TICK per tick, then as counts at the tick's end;
        a frame logged on /can/frames (``seq``: an intruder's) always gets its record, which labels it."""
        k = self.tick()
        if seq is not None or self._this_tick < RECORDS_PER_TICK:
            self._this_tick += seq is None
            t, t_ns = self.time(k)
            record = Foreign(
                tick=k,
                t=t,
                kind=kind,
                reason=reason,
                source=source,
                id=frame_id,
                length=length,
                data=data[:64].hex(),
                seq=seq,
            )
            self.recorder.foreign(t_ns, record)
        else:
            self._more[(kind, reason)] += 1

    def close_tick(self) -> None:
        """The tick's arrivals not logged one by one, as counts."""
        k = self.tick()
        t, t_ns = self.time(k)
        for (kind, reason), count in self._more.items():
            record = Foreign(tick=k, t=t, kind=kind, reason=reason, source="", length=0, data="", count=count)
            self.recorder.foreign(t_ns, record)
        self._more.clear()
        self._this_tick = 0

    def report(self, reason: str, elapsed: float, kernel_dropped: int) -> str:
        """A failure's report, naming the foreign frame that came before it, if one did, and the flood
        when what the run did not send came fast (``elapsed`` s since the run started) or overflowed
        the kernel's buffer."""
        if self.last is None:
            return reason
        flood = flood_report(self.counts["frames"] + self.counts["datagrams"], elapsed, kernel_dropped, self.last)
        before = flood or f"a frame the run did not send came before: {self.last}"
        return f"{reason}\n({before}; see /cosim/foreign in the log)"
