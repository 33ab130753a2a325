"""The bus as the log saw it (docs/metrics.md, "The bus"): frames and bits per id, the load against
the configured bit rates with exact bit stuffing (``cosim.bus.timing``), overall, of the busiest
tick and per second; on an arbitrated bus (``/cosim/wire``) per-id latency, late and replaced
frames; deadline misses, SecOC rejections and what arrived that does not belong to the run.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from typing import Any

from cosim.analysis.metrics.values import (
    BusMetrics,
    DiagnosisMetrics,
    ForeignTraffic,
    IdLatency,
    IdTraffic,
    LoadOverTime,
)
from cosim.bus.timing import frame_bits, frame_bits_worst_case
from cosim.log.topics import CanFrame, DeadlineMiss, Foreign, SecurityRejection, WirePassage

#: Bus load over time is reported per window of this much simulated time.
LOAD_WINDOW_NS = 1_000_000_000


def hex_id(frame_id: int) -> str:
    """An arbitration id as the metrics name it: ``0x080``."""
    return f"0x{frame_id:03X}"


def _rate(value: Any) -> float | None:
    return value if isinstance(value, (int, float)) and value > 0 else None


class BusScore:
    """The bus's traffic, fed record by record in file order."""

    def __init__(self, bus: dict[str, Any], sample_time: float | None) -> None:
        self.bitrate = _rate(bus.get("bitrate"))
        self.data_bitrate = _rate(bus.get("data_bitrate")) or self.bitrate
        self.fd = bus.get("fd")
        self.sample_time = sample_time
        self.by_id: dict[int, IdTraffic] = {}
        self.busy = self.busy_worst = 0.0
        self.worst_time: dict[tuple[bool, bool, bool, int], float] = {}  # a frame's shape -> its worst-case time
        self.frames = 0
        self.tick: int | None = None
        self.tick_busy, self.peak = 0.0, 0.0
        self.windows: defaultdict[int, float] = defaultdict(float)  # second of simulated time -> busy seconds in it
        # second -> seconds of wire the frames queued in it need (arbitrated)
        self.offered: defaultdict[int, float] = defaultdict(float)
        self.latency: dict[int, list[float]] = defaultdict(list)  # id -> latencies on the wire (arbitrated)
        self.late: Counter[int] = Counter()
        self.dropped: Counter[int] = Counter()
        self.misses: Counter[str] = Counter()  # node -> deadline misses
        self.foreign: Counter[str] = Counter()  # kind -> arrivals that do not belong (from /cosim/foreign)
        self.foreign_reasons: Counter[str] = Counter()
        self.foreign_ids: Counter[str] = Counter()
        self.rejected: dict[str, Counter[str]] = defaultdict(Counter)  # id -> reason -> SecOC rejections

    def _time(self, bits: tuple[int, int]) -> float:
        return bits[0] / self.bitrate + bits[1] / self.data_bitrate if self.bitrate and self.data_bitrate else 0.0

    def frame(self, frame: CanFrame, log_time: int) -> None:
        data = frame.payload_bytes
        frame_id, fd, brs, extended = int(frame.id), bool(frame.fd), bool(frame.brs), bool(frame.extended)
        bits = frame_bits(frame_id, extended, fd, brs, int(frame.dlc), data)
        entry = self.by_id.get(frame_id)
        if entry is None:
            entry = self.by_id[frame_id] = IdTraffic(frame.message)
        entry.frames += 1
        entry.bits += bits[0] + bits[1]
        self.frames += 1
        busy = self._time(bits)
        self.busy += busy
        self.windows[log_time // LOAD_WINDOW_NS] += busy
        shape = (extended, fd, brs, len(data))
        worst = self.worst_time.get(shape)
        if worst is None:
            worst = self.worst_time[shape] = self._time(frame_bits_worst_case(*shape))
        self.busy_worst += worst
        if frame.tick != self.tick:
            self.finish()
            self.tick, self.tick_busy = frame.tick, 0.0
        self.tick_busy += busy

    def passage(self, passage: WirePassage) -> None:
        """A frame's passage on the simulated wire (/cosim/wire)."""
        frame_id = int(passage.id)
        if self.bitrate:  # what the senders asked of the wire, carried or not (nominal bit rate)
            self.offered[int(float(passage.queued) * 1e9) // LOAD_WINDOW_NS] += int(passage.bits) / self.bitrate
        if passage.dropped:
            self.dropped[frame_id] += 1
            return
        self.latency[frame_id].append(float(passage.latency))
        self.late[frame_id] += bool(passage.late)

    def deadline_miss(self, miss: DeadlineMiss) -> None:
        self.misses[str(miss.node)] += 1

    def rejection(self, rejection: SecurityRejection) -> None:
        self.rejected[hex_id(int(rejection.id))][str(rejection.reason)] += 1

    def arrival(self, foreign: Foreign) -> None:
        """What arrived that does not belong to the run (/cosim/foreign)."""
        count = int(foreign.count)
        self.foreign[str(foreign.kind)] += count
        self.foreign_reasons[str(foreign.reason)] += count
        if foreign.kind == "frame" and isinstance(foreign.id, int):
            self.foreign_ids[hex_id(foreign.id)] += count

    def finish(self) -> None:
        if self.sample_time:
            self.peak = max(self.peak, self.tick_busy / self.sample_time)

    def metrics(
        self,
        ticks: int,
        lost: int | None,
        deadline_misses: int | None,
        by_sender: tuple[dict[str, int], dict[str, int]],
        intrusion_detection: dict[str, DiagnosisMetrics] | None,
        secoc_detection: DiagnosisMetrics | None = None,
    ) -> BusMetrics:
        """The scores over ``ticks`` ticks; ``deadline_misses`` the run's count (None: the log's),
        ``by_sender`` its frames lost and late per node; the intrusion detector's and SecOC's
        diagnosis scores where the run had them."""
        span = ticks * self.sample_time if self.sample_time else 0.0
        known = bool(self.bitrate) and span > 0
        return BusMetrics(
            fd=self.fd,
            bitrate=self.bitrate,
            data_bitrate=self.data_bitrate if self.fd else None,
            frames=self.frames,
            by_id={hex_id(i): e for i, e in sorted(self.by_id.items())},
            load=self.busy / span if known else None,
            load_worst_case=self.busy_worst / span if known else None,
            peak_tick_load=self.peak if known else None,
            lost=lost,
            lost_by_sender=by_sender[0],
            late_by_sender=by_sender[1],
            deadline_misses=deadline_misses if deadline_misses is not None else sum(self.misses.values()),
            deadline_misses_by_node=dict(sorted(self.misses.items())),
            foreign=ForeignTraffic(
                self.foreign["datagram"], self.foreign["frame"], dict(sorted(self.foreign_reasons.items()))
            ),
            foreign_frames=dict(sorted(self.foreign_ids.items())),
            intrusion_detection=intrusion_detection,
            secoc_detection=secoc_detection,
            secoc_rejected={i: dict(sorted(r.items())) for i, r in sorted(self.rejected.items())}
            if self.rejected
            else None,
            load_over_time=self._load_over_time(span) if known else None,
            latency=self._latency(),
        )

    def _load_over_time(self, span: float) -> LoadOverTime:
        """Load per second of simulated time (the last window only as long as the run)."""
        window = LOAD_WINDOW_NS / 1e9
        count = max(1, math.ceil(span / window - 1e-9))
        loads, offered = [], []
        for i in range(count):
            length = min(window, span - i * window) if span > i * window else window
            loads.append(round(self.windows.get(i, 0.0) / length, 6))
            offered.append(round(self.offered.get(i, 0.0) / length, 6))
        found = LoadOverTime(window, loads, max(loads))
        if self.offered:  # arbitrated: the load asked for, which may pass 100 % where the carried load cannot
            found.offered, found.offered_peak = offered, max(offered)
        return found

    def _latency(self) -> dict[str, IdLatency] | None:
        """Per id on an arbitrated bus: latency from queueing to delivery (min, median, max, s),
        frames delivered after their deadline, frames replaced before they went out."""
        ids = sorted(self.latency.keys() | self.dropped.keys())
        if not ids:
            return None
        found = {}
        for i in ids:
            values = sorted(self.latency.get(i, []))
            n = len(values)
            median = None if not n else (values[n // 2] if n % 2 else (values[n // 2 - 1] + values[n // 2]) / 2)
            found[hex_id(i)] = IdLatency(
                n,
                values[0] if n else None,
                median,
                values[-1] if n else None,
                self.late.get(i, 0),
                self.dropped.get(i, 0),
            )
        return found
