"""Metrics of a run log against its ground truth: estimation, detection and isolation, the bus.

``compute_metrics(path)`` reads the log once, in file order, and returns one JSON-ready dict
(``cosim inspect --json`` prints it). Every metric is defined in docs/metrics.md; in short, with
e_k = |x_k − x̂_k| (Euclidean norm over the whole state) and τ the sample time:

- estimation, per estimator: RMS of e_k before and from the first fault onset; the pre-fault band
  b = 2 max e_k over the second half of the ticks before the first onset; per fault, over its
  segment (from its onset to the next onset of any fault, or the end of the log), the peak of e_k
  and the recovery time (from the onset to the tick after the last one with e_k > b; null if e_k is
  still out of the band at the segment's end); the bias rejection ratio (post-fault RMS over that
  of the uniform-weight baseline: a ``pseudoinverse`` estimator without ``weights``).
- diagnosis, per estimator that publishes ``alarm`` (and optionally ``isolated_<name>`` flags):
  per fault, detection delay (first alarm tick in its segment), isolation delay and decision;
  false alarms (alarm episodes starting with no fault active), their rate per fault-free hour, and
  missed detections.
- bus: frames and bits per id, load against the configured bit rates (exact bit stuffing,
  ``cosim.bus.timing``), overall and per second, lost frames and deadline misses; on an arbitrated
  bus (``/cosim/wire``) per-id latency (min, median, max), late and replaced frames.

Memory is bounded whatever the log's length: the truth and estimate messages of a tick are held
only until the tick is complete (or ``WINDOW`` ticks old), then scored and dropped.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim.bus.codec import estimate_signal
from cosim.bus.timing import frame_bits, frame_bits_worst_case
from cosim.log.metadata import EstimatorRecord, LogMetadata, RunRecord
from cosim.log.reader import LogReader
from cosim.log.recorder import (
    DEADLINE_MISSES,
    EVENTS,
    FAULTS,
    FOREIGN,
    FRAMES,
    IDS,
    IDS_CHECKS,
    SECURITY,
    STATE,
    WIRE,
    carried_tick,
)
from estimators.base import DiagnosticKind

#: Ticks a tick waits for its missing parts (truth, estimate frames) before it is scored without them.
WINDOW = 1000
#: The pre-fault band is this many times the largest settled pre-fault error.
BAND_FACTOR = 2.0
#: Bus load over time is reported per window of this much simulated time.
LOAD_WINDOW_NS = 1_000_000_000


def compute_metrics(path: str | Path) -> dict[str, Any]:
    """The metrics of one log as a JSON-ready dict (shape in docs/metrics.md). Raises LogError only
    for a file that is not MCAP at all; damage and missing data become ``warnings`` and ``missing``."""
    with LogReader(path) as reader:
        meta = reader.metadata()
        try:
            run = _Run(meta)
        except (KeyError, TypeError, ValueError, AttributeError, IndexError) as error:  # valid JSON, damaged content
            run = _Run({})
            run.warnings.insert(
                0, f"the cosim metadata is damaged ({type(error).__name__}: {error}); the log is read as a foreign one"
            )
        summary = reader.summary()
        counts: dict[str, int] = {}
        if summary is not None and summary.statistics is not None:
            counts = {
                summary.channels[cid].topic: n
                for cid, n in summary.statistics.channel_message_counts.items()
                if cid in summary.channels
            }
            for channel in summary.channels.values():
                counts.setdefault(channel.topic, 0)
        scorer = _Scorer(run)
        scanned: dict[str, int] = defaultdict(int)
        try:
            for topic, log_time, msg in reader.messages():
                scanned[topic] += 1
                scorer.feed(topic, log_time, msg)
        except (OSError, OverflowError, MemoryError) as error:  # a damaged index points outside the file
            where = "at its start" if scorer.last_ns is None else f"after t = {scorer.last_ns / 1e9:g} s"
            scorer.warnings.append(
                f"reading stopped {where}: the file's summary is damaged ({type(error).__name__}: {error}); "
                f"the {sum(scanned.values())} messages before were read"
            )
        scorer.finish()
        warnings = reader.warnings + run.warnings + scorer.warnings
    return _report(path, run, scorer, counts or dict(scanned), warnings)


# -- what the metadata says ---------------------------------------------------------------------


class _Run:
    """The run's description from its metadata records (``cosim.log.metadata``), read leniently."""

    def __init__(self, meta: dict[str, dict[str, str]]) -> None:
        records = LogMetadata.read(meta)
        self.warnings: list[str] = list(records.warnings)
        self.missing: list[str] = []
        result = records.result
        self.status = result.status if result else "incomplete"
        self.frames_total = result.frames_total if result else None
        self.frames_lost = result.frames_lost if result else None
        self.deadline_misses = result.deadline_misses if result else None
        self.lost_by_sender = (
            {name: c.lost + c.runner_frames_missed for name, c in result.senders.items()} if result else {}
        )
        self.late_by_sender = {name: c.late for name, c in result.senders.items()} if result else {}
        self.result_ticks = result.ticks if result else None
        self.known = records.run is not None
        if records.run is None:
            self.warnings.append(
                "no cosim.run metadata: not a cosim log, or written by another program; "
                "estimator errors, fault and diagnosis metrics and the bus load are unavailable"
            )
            self.missing.append(
                "cosim.run metadata (sample time, states, estimators, faults, bus): without it only "
                "channels, message counts and the time span are reported"
            )
        if result is None:
            self.missing.append("cosim.result metadata (status, frame counts): the run did not finish writing its log")
        self.record = run = records.run or RunRecord()
        self.sample_time, self.dt_ns = run.sample_time, run.dt_ns
        self.states, self.sensors, self.actuators = run.states, run.sensors, run.actuators
        self.estimators: dict[str, EstimatorRecord] = run.estimators
        self.onset, self.onset_tick, self.bus, self.seed = run.fault_onset, run.fault_onset_tick, run.bus, run.seed
        self.faults: dict[str, dict[str, Any]] = {
            f.label: {"kind": f.kind, "targets": list(f.targets or []), "start": f.start, "end": f.end}
            for f in run.faults
        }
        if any(f.targets is None for f in run.faults):
            self.missing.append("fault targets (cosim.run faults): isolation is not scored for the faults without them")
        self.baseline = next(
            (
                name
                for name, e in self.estimators.items()
                if e.kind == "pseudoinverse" and e.params.get("weights") is None
            ),
            None,
        )

    def topic_owner(self) -> dict[str, str]:
        return self.record.estimate_topics()


# -- ticks assembled from their parts -----------------------------------------------------------


@dataclass
class _Tick:
    x: dict[str, Any] | None = None
    active: list[str] | None = None
    estimates: dict[str, dict[str, Any]] = field(default_factory=lambda: defaultdict(dict))
    ids: dict[str, Any] | None = None  # the intrusion detector's verdict (/cosim/ids)
    parts: int = 0


@dataclass
class _Segment:
    """From one fault onset (one or more faults starting at tick ``start``) to the next."""

    start: int
    labels: list[str]


class _Scorer:
    def __init__(self, run: _Run) -> None:
        self.run = run
        self.warnings: list[str] = []
        self.owner = run.topic_owner()
        self.expected_parts = (2 + len(self.owner)) if run.states else 0
        # The intrusion detector, scored as a diagnosis: its alarm ("any" check) and each check's own
        self.ids: dict[str, _DiagnosisScore] = {}
        if run.bus.get("intrusion_detector"):
            self.ids = {check: _DiagnosisScore(run, None, check) for check in ("any", *IDS_CHECKS)}
            self.expected_parts += 1 if self.expected_parts else 0
        self.pending: dict[int, _Tick] = {}
        self.next_tick = 0
        self.newest = -1
        self.ticks = 0
        self.late = 0
        self.active: set[str] = set()
        self.onsets: dict[str, int] = {}
        self.ends: dict[str, int] = {}
        self.segment: _Segment | None = None
        self.estimators = {name: _EstimationScore(run) for name in run.estimators}
        self.diagnosis: dict[str, _DiagnosisScore] = {}
        #: The alarm signal of each estimator that publishes one.
        self.alarms = {
            name: next(iter(alarms))
            for name, e in run.estimators.items()
            if (alarms := e.signals_of(DiagnosticKind.ALARM))
        }
        self.bus = _BusScore(run)
        self.lost_events = 0
        self.misses: dict[str, int] = defaultdict(int)
        self.foreign: Counter[str] = Counter()  # kind -> arrivals that do not belong (from /cosim/foreign)
        self.foreign_reasons: Counter[str] = Counter()
        self.foreign_ids: Counter[str] = Counter()
        self.rejected: dict[str, Counter[str]] = defaultdict(Counter)  # id -> reason -> SecOC rejections
        self.broken: set[str] = set()
        self.first_ns: int | None = None
        self.last_ns: int | None = None

    # feeding, in file order

    def feed(self, topic: str, log_time: int, msg: Any) -> None:
        self.first_ns = log_time if self.first_ns is None else min(self.first_ns, log_time)
        self.last_ns = log_time if self.last_ns is None else max(self.last_ns, log_time)
        if topic in self.broken or not isinstance(msg, dict):
            return
        try:
            if topic == FRAMES:
                self.bus.frame(msg, log_time)
            elif topic == WIRE:
                self.bus.passage(msg)
            elif topic == EVENTS:
                if msg.get("event") == "frames_lost":
                    self.lost_events += int(msg.get("count", 1))
            elif topic == DEADLINE_MISSES:
                self.misses[str(msg["node"])] += 1
            elif topic == SECURITY:
                self.rejected[f"0x{int(msg['id']):03X}"][str(msg["reason"])] += 1
            elif topic == FOREIGN:
                count = int(msg.get("count", 1))
                self.foreign[str(msg["kind"])] += count
                self.foreign_reasons[str(msg["reason"])] += count
                if msg.get("kind") == "frame" and isinstance(msg.get("id"), int):
                    self.foreign_ids[f"0x{msg['id']:03X}"] += count
            elif self.expected_parts and self.run.dt_ns:
                self._part(topic, log_time, msg, self.run.dt_ns)
        except (KeyError, TypeError, ValueError) as error:
            self.broken.add(topic)
            self.warnings.append(
                f"{topic}: a message at t = {log_time / 1e9:g} s does not have the fields cosim writes "
                f"({type(error).__name__}: {error}); the topic is ignored from there on"
            )

    def _part(self, topic: str, log_time: int, msg: dict[str, Any], dt_ns: int) -> None:
        if topic == STATE:
            k = int(msg["tick"])
            self._tick(k).x = msg
        elif topic == FAULTS:
            k = int(msg["tick"])
            self._tick(k).active = list(msg["active"])
        elif topic == IDS and self.ids:
            k = int(msg["tick"])
            self._tick(k).ids = msg
        elif topic in self.owner:
            k = carried_tick(log_time // dt_ns, msg["tick"])
            if k < self.next_tick:
                self.late += 1
                return
            self._tick(k).estimates[self.owner[topic]].update(msg)
        else:
            return
        tick = self.pending[k]
        tick.parts += 1
        self.newest = max(self.newest, k)
        self._drain(self.newest - WINDOW)

    def _tick(self, k: int) -> _Tick:
        if k not in self.pending:
            self.pending[k] = _Tick()
        return self.pending[k]

    def _drain(self, force_below: int) -> None:
        """Score ticks in order: each once complete, or incomplete once older than ``force_below``."""
        while self.pending:
            tick = self.pending.get(self.next_tick)
            if tick is not None and (tick.parts >= self.expected_parts or self.next_tick < force_below):
                self._score(self.next_tick, self.pending.pop(self.next_tick))
            elif tick is None and self.next_tick < force_below:
                pass  # never logged (a skipped chunk): nothing to score
            else:
                return
            self.next_tick += 1

    def finish(self) -> None:
        for k in sorted(self.pending):
            self.next_tick = k
            self._score(k, self.pending.pop(k))
        self._close_segment()
        self.bus.finish()
        if self.late:
            self.warnings.append(
                f"{self.late} estimate messages arrived more than {WINDOW} ticks late and were not scored"
            )

    # scoring, tick by tick in order

    def _score(self, k: int, tick: _Tick) -> None:
        if tick.x is not None:
            self.ticks = max(self.ticks, k + 1)
        active = self.active if tick.active is None else set(tick.active)
        for label in self.active - active:
            self.ends.setdefault(label, k)
        started = [label for label in self.run.faults if label in active and label not in self.active]
        started += sorted(label for label in active - self.active if label not in self.run.faults)
        if started:
            self._close_segment()
            self.segment = _Segment(k, started)
            for label in started:
                self.onsets.setdefault(label, k)
        self.active = active
        for name, estimate in tick.estimates.items():
            if tick.x is not None and all(
                isinstance(estimate.get(estimate_signal(s)), (int, float)) for s in self.run.states
            ):
                error = math.sqrt(math.fsum((tick.x[s] - estimate[estimate_signal(s)]) ** 2 for s in self.run.states))
                self.estimators[name].add(k, error, self.segment)
            alarm = self.alarms.get(name)
            if alarm is not None and isinstance(estimate.get(alarm), (int, float)):
                if name not in self.diagnosis:
                    self.diagnosis[name] = _DiagnosisScore(self.run, name, alarm)
                self.diagnosis[name].add(k, estimate, active, self.segment)
        if tick.ids is not None:
            verdict = {"any": float(bool(tick.ids["alarm"]))} | {c: float(tick.ids[c] > 0) for c in IDS_CHECKS}
            for score in self.ids.values():
                score.add(k, verdict, active, self.segment)

    def _close_segment(self) -> None:
        if self.segment is None:
            return
        scores: list[_EstimationScore | _DiagnosisScore] = [
            *self.estimators.values(),
            *self.diagnosis.values(),
            *self.ids.values(),
        ]
        for score in scores:
            score.close(self.segment)
        self.segment = None


# -- estimation ---------------------------------------------------------------------------------


class _EstimationScore:
    def __init__(self, run: _Run) -> None:
        self.run = run
        self.sums = {"pre": [0.0, 0], "post": [0.0, 0]}
        self.final: tuple[int, float | None] = (-1, None)
        self.settled_max: float | None = None
        self.scored = 0
        self.seg_peak: tuple[float, int] | None = None
        self.seg_last_out: int | None = None
        self.seg_last: tuple[int, float] | None = None
        self.faults: dict[str, dict[str, Any]] = {}

    @property
    def band(self) -> float | None:
        return None if self.settled_max is None else BAND_FACTOR * self.settled_max

    def add(self, k: int, error: float, segment: _Segment | None) -> None:
        onset = self.run.onset_tick
        window = "post" if onset is not None and k >= onset else "pre"
        self.sums[window][0] += error * error
        self.sums[window][1] += 1
        self.scored += 1
        if k > self.final[0]:
            self.final = (k, error)
        if onset is not None and onset // 2 <= k < onset:
            self.settled_max = error if self.settled_max is None else max(self.settled_max, error)
        if segment is not None:
            if self.seg_peak is None or error > self.seg_peak[0]:
                self.seg_peak = (error, k)
            band = self.band
            if band is not None and error > band:
                self.seg_last_out = k
            self.seg_last = (k, error)

    def close(self, segment: _Segment) -> None:
        dt, band = self.run.sample_time, self.band
        assert dt is not None, "segments start at scored ticks, and ticks are scored only with a sample time"
        recovery = None
        if band is not None and self.seg_last is not None and self.seg_last[1] <= band:
            recovery = 0.0 if self.seg_last_out is None else round((self.seg_last_out + 1 - segment.start) * dt, 9)
        for label in segment.labels:
            self.faults[label] = {
                "peak_error": None if self.seg_peak is None else self.seg_peak[0],
                "peak_at": None if self.seg_peak is None else round((self.seg_peak[1] - segment.start) * dt, 9),
                "recovery_time": recovery,
                "recovered": recovery is not None,
            }
        self.seg_peak = self.seg_last_out = self.seg_last = None

    def rms(self, window: str) -> float | None:
        total, n = self.sums[window]
        return math.sqrt(total / n) if n else None


# -- detection and isolation --------------------------------------------------------------------


class _DiagnosisScore:
    """Detection and isolation by one estimator that publishes an alarm (and isolation flags)."""

    def __init__(self, run: _Run, name: str | None, alarm: str) -> None:
        self.run = run
        record = run.estimators[name] if name is not None else None  # None: the intrusion detector, no flags
        self.alarm = alarm
        #: flag (what it isolates, e.g. a thruster T1) → its signal; and what the flag names as faulty
        isolation = record.signals_of(DiagnosticKind.ISOLATION) if record is not None else {}
        self.signals = {target or signal: signal for signal, target in sorted(isolation.items())}
        self.flags = sorted(self.signals)
        self.targets = (
            {flag: record.isolates.get(signal, []) for flag, signal in self.signals.items()} if record else {}
        )
        self.alarm_prev = False
        self.scored = 0
        self.fault_free_ticks = 0
        self.false_alarms = 0
        self.alarm_ticks = 0
        self.open: dict[str, dict[str, Any]] = {}
        self.faults: dict[str, dict[str, Any]] = {}

    def expected(self, label: str) -> set[str]:
        """The flags whose targets meet the targets of fault ``label``."""
        targets = set(self.run.faults.get(label, {}).get("targets", []))
        return {flag for flag, names in self.targets.items() if targets & set(names)}

    def add(self, k: int, estimate: dict[str, Any], active: set[str], segment: _Segment | None) -> None:
        alarm = estimate[self.alarm] > 0.5
        raised = {
            flag
            for flag, signal in self.signals.items()
            if isinstance(v := estimate.get(signal), (int, float)) and v > 0.5
        }
        self.scored += 1
        self.alarm_ticks += alarm
        if not active:
            self.fault_free_ticks += 1
            self.false_alarms += alarm and not self.alarm_prev
        if segment is not None:
            for label in segment.labels:
                state = self.open.setdefault(
                    label,
                    {
                        "start": segment.start,
                        "alarm_before_onset": self.alarm_prev,
                        "detected": None,
                        "isolated": None,
                        "decision": None,
                        "correct": None,
                        "wrong": False,
                    },
                )
                if state["detected"] is None and alarm:
                    state["detected"] = k
                if state["isolated"] is None and raised:
                    # A fault is isolated once all its flags are up (a double fault's second thruster may
                    # be named later than the first); a flag no active fault explains, up to then, is wrong.
                    allowed = set().union(*(self.expected(g) for g in active))
                    state["wrong"] |= not raised <= allowed
                    if self.expected(label) <= raised:
                        state["isolated"], state["decision"] = k, sorted(raised)
                        state["correct"] = not state["wrong"]
        self.alarm_prev = alarm

    def close(self, segment: _Segment) -> None:
        dt = self.run.sample_time

        def since(k):
            return None if k is None else round((k - segment.start) * dt, 9)

        for label in segment.labels:
            state = self.open.pop(label, None)
            if state is None:  # no alarm value in the whole segment
                continue
            isolable = bool(self.expected(label))
            correct = state["correct"]
            if correct is None and isolable:
                correct = False  # never isolated
            self.faults[label] = {
                "detected": state["detected"] is not None,
                "detection_delay": since(state["detected"]),
                "alarm_before_onset": state["alarm_before_onset"],
                "isolable": isolable if self.flags else None,
                "expected": sorted(self.expected(label)) if self.flags else None,
                "isolation_delay": since(state["isolated"]),
                "isolated": state["decision"],
                "isolation_correct": correct if self.flags else None,
            }


def _verdict(verdict: _DiagnosisScore, dt: float) -> dict[str, Any]:
    """A diagnosis's scores: false alarms (per hour of fault-free time), and per fault detection
    (delay, missed) and isolation (docs/metrics.md); the intrusion detector's too."""
    hours = verdict.fault_free_ticks * dt / 3600 if dt else 0.0
    return {
        "isolation_flags": verdict.targets,
        "ticks_scored": verdict.scored,
        "alarm_time_s": round(verdict.alarm_ticks * dt, 9),
        "fault_free_time_s": round(verdict.fault_free_ticks * dt, 9),
        "false_alarms": verdict.false_alarms,
        "false_alarm_rate_per_hour": verdict.false_alarms / hours if hours else None,
        "missed_detections": sum(not verdict.faults[label]["detected"] for label in verdict.faults),
        "faults": verdict.faults,
    }


# -- the bus ------------------------------------------------------------------------------------


class _BusScore:
    def __init__(self, run: _Run) -> None:
        bus = run.bus

        def rate(value):
            return value if isinstance(value, (int, float)) and value > 0 else None

        self.bitrate = rate(bus.get("bitrate"))
        self.data_bitrate = rate(bus.get("data_bitrate")) or self.bitrate
        self.fd = bus.get("fd")
        self.sample_time = run.sample_time
        self.by_id: dict[int, dict[str, Any]] = {}
        self.busy = self.busy_worst = 0.0
        self.frames = 0
        self.tick, self.tick_busy, self.peak = None, 0.0, 0.0
        self.windows: defaultdict[int, float] = defaultdict(float)  # second of simulated time -> busy seconds in it
        self.latency: dict[int, list[float]] = defaultdict(list)  # id -> latencies on the wire (arbitrated)
        self.late: Counter[int] = Counter()
        self.dropped: Counter[int] = Counter()
        self.offered: defaultdict[int, float] = defaultdict(
            float
        )  # second -> seconds of wire the frames queued in it need

    def _time(self, bits: tuple[int, int]) -> float:
        return bits[0] / self.bitrate + bits[1] / self.data_bitrate if self.bitrate else 0.0

    def passage(self, msg: dict[str, Any]) -> None:
        """A frame's passage on the simulated wire (/cosim/wire)."""
        frame_id = int(msg["id"])
        if self.bitrate:  # what the senders asked of the wire, carried or not (nominal bit rate)
            self.offered[int(float(msg["queued"]) * 1e9) // LOAD_WINDOW_NS] += int(msg["bits"]) / self.bitrate
        if msg.get("dropped"):
            self.dropped[frame_id] += 1
            return
        self.latency[frame_id].append(float(msg["latency"]))
        self.late[frame_id] += bool(msg["late"])

    def frame(self, msg: dict[str, Any], log_time: int = 0) -> None:
        data = bytes.fromhex(msg["data"])
        fd, brs, extended = bool(msg["fd"]), bool(msg["brs"]), bool(msg["extended"])
        bits = frame_bits(int(msg["id"]), extended, fd, brs, int(msg["dlc"]), data)
        worst = frame_bits_worst_case(extended, fd, brs, len(data))
        entry = self.by_id.setdefault(int(msg["id"]), {"message": msg.get("message"), "frames": 0, "bits": 0})
        entry["frames"] += 1
        entry["bits"] += bits[0] + bits[1]
        self.frames += 1
        busy = self._time(bits)
        self.busy += busy
        self.windows[log_time // LOAD_WINDOW_NS] += busy
        self.busy_worst += self._time(worst)
        if msg.get("tick") != self.tick:
            self.finish()
            self.tick, self.tick_busy = msg.get("tick"), 0.0
        self.tick_busy += busy

    def finish(self) -> None:
        if self.sample_time:
            self.peak = max(self.peak, self.tick_busy / self.sample_time)

    def report(self, run: _Run, ticks: int, lost: int, misses: dict[str, int], scorer: _Scorer) -> dict[str, Any]:
        span = ticks * self.sample_time if self.sample_time else 0.0
        known = bool(self.bitrate) and span > 0
        deadline = run.deadline_misses if run.deadline_misses is not None else sum(misses.values())
        return {
            "fd": self.fd,
            "bitrate": self.bitrate,
            "data_bitrate": self.data_bitrate if self.fd else None,
            "frames": self.frames,
            "by_id": {f"0x{i:03X}": e for i, e in sorted(self.by_id.items())},
            "load": self.busy / span if known else None,
            "load_worst_case": self.busy_worst / span if known else None,
            "peak_tick_load": self.peak if known else None,
            "lost": lost,
            "lost_by_sender": run.lost_by_sender,
            "late_by_sender": run.late_by_sender,
            "deadline_misses": deadline,
            "deadline_misses_by_node": dict(sorted(misses.items())),
            "foreign": {
                "datagrams": scorer.foreign["datagram"],
                "frames": scorer.foreign["frame"],
                "by_reason": dict(sorted(scorer.foreign_reasons.items())),
            },
            "foreign_frames": dict(sorted(scorer.foreign_ids.items())),
            # only where the run had the intrusion detector (/cosim/ids)
            **(
                {"intrusion_detection": {c: _verdict(v, self.sample_time) for c, v in scorer.ids.items()}}
                if scorer.ids and self.sample_time
                else {}
            ),
            # only where SecOC dropped frames (/cosim/security)
            **(
                {"secoc_rejected": {i: dict(sorted(r.items())) for i, r in sorted(scorer.rejected.items())}}
                if scorer.rejected
                else {}
            ),
            "load_over_time": self._load_over_time(span) if known else None,
            "latency": self._latency(),
        }

    def _load_over_time(self, span: float) -> dict[str, Any]:
        """Load per second of simulated time (the last window only as long as the run)."""
        window = LOAD_WINDOW_NS / 1e9
        count = max(1, math.ceil(span / window - 1e-9))
        loads, offered = [], []
        for i in range(count):
            length = min(window, span - i * window) if span > i * window else window
            loads.append(round(self.windows.get(i, 0.0) / length, 6))
            offered.append(round(self.offered.get(i, 0.0) / length, 6))
        out: dict[str, Any] = {"window_s": window, "load": loads, "peak": max(loads)}
        if self.offered:  # arbitrated: the load asked for, which may pass 100 % where the carried load cannot
            out |= {"offered": offered, "offered_peak": max(offered)}
        return out

    def _latency(self) -> dict[str, Any] | None:
        """Per id on an arbitrated bus: latency from queueing to delivery (min, median, max, s),
        frames delivered after their deadline, frames replaced before they went out."""
        ids = sorted(self.latency.keys() | self.dropped.keys())
        if not ids:
            return None
        out = {}
        for i in ids:
            values = sorted(self.latency.get(i, []))
            n = len(values)
            median = None if not n else (values[n // 2] if n % 2 else (values[n // 2 - 1] + values[n // 2]) / 2)
            out[f"0x{i:03X}"] = {
                "frames": n,
                "min": values[0] if n else None,
                "median": median,
                "max": values[-1] if n else None,
                "late": self.late.get(i, 0),
                "dropped": self.dropped.get(i, 0),
            }
        return out


# -- the report ---------------------------------------------------------------------------------


def _report(
    path: str | Path, run: _Run, scorer: _Scorer, channels: dict[str, int], warnings: list[str]
) -> dict[str, Any]:
    dt = run.sample_time
    ticks = scorer.ticks if run.known else channels.get(STATE, 0)
    if run.result_ticks is not None:  # the ticks the run completed (a stopped run logs the truth of one more)
        ticks = min(ticks, run.result_ticks) if ticks else run.result_ticks

    def seconds(k):
        return None if k is None or dt is None else round(k * dt, 9)

    lost = run.frames_lost if run.frames_lost is not None else scorer.lost_events
    estimators = {}
    baseline = scorer.estimators.get(run.baseline) if run.baseline else None
    for name, score in scorer.estimators.items():
        post, base = score.rms("post"), baseline.rms("post") if baseline else None
        estimators[name] = {
            "kind": run.estimators[name].kind,
            "rms_pre_fault": score.rms("pre"),
            "rms_post_fault": post,
            "final_error": score.final[1],
            "ticks_scored": score.scored,
            "band": score.band,
            "bias_rejection_ratio": post / base if post is not None and base else None,
            "faults": score.faults,
        }
    diagnosis = {}
    for name, verdict in scorer.diagnosis.items():
        assert dt is not None, "diagnosis is scored at ticks, and ticks are scored only with a sample time"
        diagnosis[name] = {"kind": run.estimators[name].kind if name in run.estimators else None} | _verdict(
            verdict, dt
        )
    faults = {
        label: {**info, "onset": seconds(scorer.onsets.get(label)), "cleared": seconds(scorer.ends.get(label))}
        for label, info in run.faults.items()
    }
    for label in scorer.onsets.keys() - faults.keys():  # active in the truth but absent from the metadata
        faults[label] = {
            "kind": None,
            "targets": [],
            "start": None,
            "end": None,
            "onset": seconds(scorer.onsets[label]),
            "cleared": seconds(scorer.ends.get(label)),
        }
    missing = list(run.missing)
    if run.known:
        for topic, what in (
            (STATE, "estimation errors"),
            (FAULTS, "per-fault onsets, detection and isolation"),
            (FRAMES, "frames per id and bus load"),
        ):
            if not channels.get(topic):
                missing.append(f"{topic} messages: no {what}")
        if scorer.bus.frames and not scorer.bus.bitrate:
            missing.append("the bus bit rate (cosim.run.bus): no bus load")
    span = (
        None
        if scorer.first_ns is None or scorer.last_ns is None  # set together
        else round((scorer.last_ns - scorer.first_ns) / 1e9, 9)
    )
    return {
        "file": str(path),
        "scenario": run.record.scenario,
        "source": run.record.source,
        "seed": run.seed,
        "status": run.status,
        "sample_time": dt,
        "ticks": ticks,
        "duration_s": round(ticks * dt, 9) if dt else None,
        "time_span_s": span,
        "channels": dict(sorted(channels.items())),
        "frames": {
            "total": run.frames_total if run.frames_total is not None else channels.get(FRAMES, 0),
            "lost": lost,
        },
        "fault_onset": run.onset,
        "faults": faults,
        "estimators": estimators,
        "baseline": run.baseline,
        "diagnosis": diagnosis,
        "bus": scorer.bus.report(run, ticks, lost, scorer.misses, scorer) if run.known else None,
        "missing": missing,
        "warnings": warnings,
    }
