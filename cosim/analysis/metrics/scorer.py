"""A log's messages scored in file order: each read through its topic's record
(``cosim.log.topics``), ticks assembled from their parts (truth, estimates, the intrusion
detector's verdict, SecOC's rejections) and scored in tick order, fault onsets cutting the run into segments.

Memory is bounded whatever the log's length: the parts of a tick are held only until the tick is
complete (or ``WINDOW`` ticks old), then scored and dropped.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cosim.analysis.metrics.bus import BusScore
from cosim.analysis.metrics.diagnosis import DiagnosisScore
from cosim.analysis.metrics.estimation import EstimationScore
from cosim.analysis.metrics.facts import RunFacts
from cosim.analysis.metrics.segments import Segment
from cosim.bus.codec import estimate_signal, estimated_state
from cosim.log.topics import (
    FAULTS,
    IDS,
    IDS_CHECKS,
    STATE,
    CanFrame,
    DeadlineMiss,
    Event,
    Foreign,
    IntrusionVerdict,
    Record,
    SecurityRejection,
    Signals,
    TruthFaults,
    TruthState,
    WirePassage,
)
from estimators.base import DiagnosticKind

#: Ticks a tick waits for its missing parts (truth, estimate frames) before it is scored without them.
WINDOW = 1000


@dataclass
class Tick:
    """What the log holds of one tick so far."""

    x: dict[str, Any] | None = None
    active: list[str] | None = None
    estimates: dict[str, dict[str, Any]] = field(default_factory=lambda: defaultdict(dict))
    ids: dict[str, float] | None = None  # the intrusion detector's alarm ("any") and checks, raised or not
    parts: int = 0


class Scorer:
    """Every score of a run, fed its log's messages in file order."""

    def __init__(
        self,
        run: RunFacts,
        bounds: Mapping[str, Mapping[str, tuple[float, float]]] | None = None,
        authenticated: Sequence[str] = (),
    ) -> None:
        """``bounds``: each estimator's estimate signals' bus ranges; ``authenticated``: the messages
        SecOC guards (from the logged DBC)."""
        self.run = run
        #: Per estimator, each estimate signal's bus range (from the logged DBC), its bounds within
        #: half a quantum: a decoded value there was saturated by the node.
        self.bounds = dict(bounds or {})
        self.warnings: list[str] = []
        self.owner = run.record.estimate_topics()
        self.expected_parts = (2 + len(self.owner)) if run.states else 0
        # The intrusion detector, scored as a diagnosis: its alarm ("any" check) and each check's own
        self.ids: dict[str, DiagnosisScore] = {}
        if run.bus.get("intrusion_detector"):
            self.ids = {check: DiagnosisScore(check, run.faults) for check in ("any", *IDS_CHECKS)}
            self.expected_parts += 1 if self.expected_parts else 0
        # SecOC, scored as a diagnosis: a tick with a rejected frame raises its alarm, and the
        # rejected messages are its isolation flags (a spoofed or replayed message names itself)
        self.secoc: DiagnosisScore | None = None
        self.rejected: dict[int, set[str]] = defaultdict(set)
        if run.bus.get("authentication") == "secoc" and authenticated:
            self.secoc = DiagnosisScore("alarm", run.faults, {m: (m, [m]) for m in authenticated})
        self.pending: dict[int, Tick] = {}
        self.next_tick = 0
        self.newest = -1
        self.ticks = 0
        self.late = 0
        self.active: set[str] = set()
        self.onsets: dict[str, int] = {}
        self.ends: dict[str, int] = {}
        self.segment: Segment | None = None
        self.estimators = {name: EstimationScore(run.onset_tick, run.sample_time) for name in run.estimators}
        self.diagnosis: dict[str, DiagnosisScore] = {}
        #: The alarm signal of each estimator that publishes one.
        self.alarms = {
            name: next(iter(alarms))
            for name, e in run.estimators.items()
            if (alarms := e.signals_of(DiagnosticKind.ALARM))
        }
        self.bus = BusScore(run.bus, run.sample_time)
        self.lost_events = 0
        self.broken: set[str] = set()
        self.first_ns: int | None = None
        self.last_ns: int | None = None
        bus = self.bus
        self._reads: dict[str, bool] = {}
        #: The topics read as records: each topic's record and what takes one (at its log time).
        self._topics: dict[str, tuple[type[Record], Callable[[Any, int], None]]] = {
            CanFrame.TOPIC: (CanFrame, bus.frame),
            WirePassage.TOPIC: (WirePassage, lambda r, t: bus.passage(r)),
            Event.TOPIC: (Event, lambda r, t: self._event(r)),
            DeadlineMiss.TOPIC: (DeadlineMiss, lambda r, t: bus.deadline_miss(r)),
            SecurityRejection.TOPIC: (SecurityRejection, lambda r, t: self._rejection(r)),
            Foreign.TOPIC: (Foreign, lambda r, t: bus.arrival(r)),
        }

    # feeding, in file order

    def reads(self, topic: str) -> bool:
        """Whether ``feed`` looks into a message of ``topic`` (else only its log time counts: a
        reader may hand ``seen`` the time instead and skip decoding the message). ``feed`` itself
        goes by it, so a reader that skips what it says is skipped scores the same."""
        reads = self._reads.get(topic)
        if reads is None:  # the answer is the scorer's settings', fixed at its start: kept per topic
            parts = bool(self.expected_parts and self.run.dt_ns)
            reads = self._reads[topic] = topic in self._topics or (
                parts and (topic in (STATE, FAULTS) or topic in self.owner or (topic == IDS and bool(self.ids)))
            )
        return reads

    def seen(self, log_time: int) -> None:
        """A message at ``log_time`` that the scores do not read: the log's time span only."""
        if self.last_ns is None or self.first_ns is None:  # set together
            self.first_ns = self.last_ns = log_time
        elif log_time > self.last_ns:
            self.last_ns = log_time
        elif log_time < self.first_ns:
            self.first_ns = log_time

    def feed(self, topic: str, log_time: int, msg: Any) -> None:
        self.seen(log_time)
        if topic in self.broken or not isinstance(msg, dict) or not self.reads(topic):
            return
        try:
            read = self._topics.get(topic)
            if read is not None:
                read[1](read[0].read(msg), log_time)
            else:
                assert self.run.dt_ns  # reads(): a tick's parts only with a sample time
                self._part(topic, log_time, msg, self.run.dt_ns)
        except (KeyError, TypeError, ValueError) as error:
            self._broken(topic, log_time, error)

    def feed_record(self, topic: str, log_time: int, record: Record) -> None:
        """A message of one of the topics read as records, as its record (a run scored while it
        goes hands the record it would have logged): scored as ``feed`` scores the message it reads."""
        self.seen(log_time)
        if topic in self.broken:
            return
        try:
            self._topics[topic][1](record, log_time)
        except (KeyError, TypeError, ValueError) as error:
            self._broken(topic, log_time, error)

    def tick(self, k: int, tick: Tick) -> None:
        """A whole tick handed in order by a run that logs nothing (a batched run,
        ``cosim.campaign.batch``): scored as the same complete tick read from its log."""
        self._score(k, tick)
        self.next_tick = k + 1

    def records(self, topic: str) -> bool:
        """Whether ``topic`` is one that ``feed_record`` takes."""
        return topic in self._topics

    def _broken(self, topic: str, log_time: int, error: Exception) -> None:
        self.broken.add(topic)
        self.warnings.append(
            f"{topic}: a message at t = {log_time / 1e9:g} s does not have the fields cosim writes "
            f"({type(error).__name__}: {error}); the topic is ignored from there on"
        )

    def _rejection(self, rejection: SecurityRejection) -> None:
        self.bus.rejection(rejection)
        if self.secoc is None:
            return
        k = int(rejection.tick)
        if k < self.next_tick:
            self.late += 1
        else:
            self.rejected[k].add(rejected_message(rejection))

    def _event(self, event: Event) -> None:
        if event.event == "frames_lost":
            self.lost_events += int(event.count)

    def _part(self, topic: str, log_time: int, msg: dict[str, Any], dt_ns: int) -> None:
        if topic == STATE:
            state = TruthState.read(msg)
            self.state(int(state.tick), state.values)
        elif topic == FAULTS:
            faults = TruthFaults.read(msg)
            self.faults(int(faults.tick), list(faults.active))
        elif topic == IDS and self.ids:
            verdict = IntrusionVerdict.read(msg)
            self.verdict(int(verdict.tick), bool(verdict.alarm), verdict.checks())
        elif topic in self.owner:
            signals = Signals.read(msg, log_time // dt_ns)
            self.estimate(self.owner[topic], signals.tick, signals.values)

    # a tick's parts, as the log's messages give them (a batched run that logs nothing hands them
    # itself, in the order its log would hold them: ``cosim.campaign.batch_wire``)

    def state(self, k: int, x: dict[str, Any]) -> None:
        """The truth's state of tick k (``/truth/state``), by state."""
        self._tick(k).x = x
        self._counted(k)

    def faults(self, k: int, active: list[str]) -> None:
        """The faults active at tick k (``/truth/faults``), by label."""
        self._tick(k).active = active
        self._counted(k)

    def verdict(self, k: int, alarm: bool, checks: Mapping[str, int]) -> None:
        """The intrusion detector's verdict on tick k (``/cosim/ids``): its alarm, each check's ids."""
        self._tick(k).ids = {"any": float(alarm)} | {check: float(count > 0) for check, count in checks.items()}
        self._counted(k)

    def estimate(self, name: str, k: int, values: dict[str, Any]) -> None:
        """One of estimator ``name``'s frames of tick k, its decoded signals (``/can/<message>``)."""
        if k < self.next_tick:
            self.late += 1
            return
        self._tick(k).estimates[name].update(values)
        self._counted(k)

    def _counted(self, k: int) -> None:
        self.pending[k].parts += 1
        self.newest = max(self.newest, k)
        self._drain(self.newest - WINDOW)

    def _tick(self, k: int) -> Tick:
        if k not in self.pending:
            self.pending[k] = Tick()
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
        for name, score in self.estimators.items():
            for signal, (ticks, first) in sorted(score.saturated.items()):
                since = "" if self.run.sample_time is None else f" from t = {self.run.seconds(first):g} s"
                self.warnings.append(
                    f"{name}: {signal} at its bus range's bound on {ticks} ticks{since} (saturated by the node: "
                    f"the estimator diverged, or widen the range with [bus.states.{estimated_state(signal)}])"
                )
        if self.late:
            self.warnings.append(
                f"{self.late} estimate or SecOC rejection messages arrived after their tick was scored"
            )

    # scoring, tick by tick in order

    def _score(self, k: int, tick: Tick) -> None:
        if tick.x is not None:
            self.ticks = max(self.ticks, k + 1)
        active = self.active if tick.active is None else set(tick.active)
        self._segments(k, active)
        states = self.run.states
        for name, estimate in tick.estimates.items():
            x = tick.x
            if x is not None and all(isinstance(estimate.get(estimate_signal(s)), (int, float)) for s in states):
                error = math.sqrt(math.fsum((x[s] - estimate[estimate_signal(s)]) ** 2 for s in states))
                self.estimators[name].add(k, error, self.segment)
            for signal, (lo, hi) in self.bounds.get(name, {}).items():
                if not lo < estimate.get(signal, 0.0) < hi:
                    self.estimators[name].saturation(k, signal)
            alarm = self.alarms.get(name)
            if alarm is not None and isinstance(estimate.get(alarm), (int, float)):
                if name not in self.diagnosis:
                    self.diagnosis[name] = DiagnosisScore.of(alarm, self.run.estimators[name], self.run.faults)
                self.diagnosis[name].add(k, estimate, active, self.segment)
        self.score_bus(k, tick.ids, self.rejected.pop(k, set()), active)

    def score_bus(self, k: int, ids: dict[str, float] | None, rejected: set[str], active: set[str]) -> None:
        """The bus's own schemes at tick k: the intrusion detector's verdict (``ids``: its alarm and
        each check, None where it published none) and the messages SecOC ``rejected``."""
        if ids is not None:
            for score in self.ids.values():
                score.add(k, ids, active, self.segment)
        if self.secoc is not None:
            self.secoc.add(k, {"alarm": float(bool(rejected))} | dict.fromkeys(rejected, 1.0), active, self.segment)

    def _segments(self, k: int, active: set[str]) -> None:
        """Onsets and clearances at tick ``k``: a fault that starts opens a new segment."""
        for label in self.active - active:
            self.ends.setdefault(label, k)
        started = [label for label in self.run.faults if label in active and label not in self.active]
        started += sorted(label for label in active - self.active if label not in self.run.faults)
        if started:
            self._close_segment()
            self.segment = Segment(k, started)
            for label in started:
                self.onsets.setdefault(label, k)
        self.active = active

    def _close_segment(self) -> None:
        if self.segment is None:
            return
        for estimation in self.estimators.values():
            estimation.close(self.segment)
        dt = self.run.sample_time
        assert dt is not None, "segments start at scored ticks, and ticks are scored only with a sample time"
        for diagnosis in (*self.diagnosis.values(), *self.ids.values(), *([self.secoc] if self.secoc else [])):
            diagnosis.close(self.segment, dt)
        self.segment = None


class TickBatch:
    """The scorers of K runs of one plan, fed whole ticks together by a batched run
    (``cosim.campaign.batch``): ``Scorer.tick``'s scores, with what is the same arithmetic for every
    run done on arrays (the differences x − x̂, the bounds) and what is each run's own done per run
    (its error's exact sum, its sums and segments, its diagnosis). ``signals``: each estimator's
    signals, in the order of the columns it is given."""

    def __init__(self, scorers: Sequence[Scorer], signals: Mapping[str, Sequence[str]], states: Sequence[str]) -> None:
        self.scorers = list(scorers)
        run = self.scorers[0].run
        self.x_columns = [list(states).index(s) for s in run.states]
        self.estimators = []
        for name, names in signals.items():
            column = {signal: i for i, signal in enumerate(names)}
            scored = name in run.estimators and all(estimate_signal(s) in column for s in run.states)
            bounds = self.scorers[0].bounds.get(name, {})
            checked = [(column[signal], signal, lo, hi) for signal, (lo, hi) in bounds.items() if signal in column]
            self.estimators.append(
                (
                    name,
                    [column[estimate_signal(s)] for s in run.states] if scored else None,
                    [c for c, _, _, _ in checked],
                    np.array([lo for _, _, lo, _ in checked]),
                    np.array([hi for _, _, _, hi in checked]),
                    [signal for _, signal, _, _ in checked],
                    self.scorers[0].alarms.get(name) in column,
                    list(names),
                )
            )
        self._active: list[tuple[str, ...] | None] = [() for _ in self.scorers]  # the last each scorer had

    def tick(
        self,
        k: int,
        rows: np.ndarray,
        x: np.ndarray,
        active: Sequence[tuple[str, ...]],
        values: Sequence[np.ndarray],
        bus: BusVerdicts | None = None,
    ) -> None:
        """Tick k of the runs ``rows``: the truth x (K, states), each run's active faults (by run),
        each estimator's signals as its frames carry them (K, signals), what the bus's own schemes
        said of the tick (``bus``: the intrusion detector's verdicts, SecOC's rejections)."""
        scorers = self.scorers
        for r in rows:
            scorer = scorers[r]
            scorer.ticks = max(scorer.ticks, k + 1)
            if active[r] != self._active[r]:
                self._active[r] = active[r]
                scorer._segments(k, set(active[r]))
            scorer.next_tick = k + 1
        truth = x[rows][:, self.x_columns]
        for (name, states, checked, lo, hi, names, alarm, signals), v in zip(self.estimators, values):
            v = v[rows]
            if states is not None:
                differences = (truth - v[:, states]).tolist()
                for r, d in zip(rows, differences):
                    scorer = scorers[r]
                    scorer.estimators[name].add(k, math.sqrt(math.fsum(e**2 for e in d)), scorer.segment)
            if checked:
                out = ~((lo < v[:, checked]) & (v[:, checked] < hi))
                for i, j in zip(*np.nonzero(out)):
                    scorers[rows[i]].estimators[name].saturation(k, names[j])
            if alarm:
                for r, row in zip(rows, v.tolist()):
                    scorer = scorers[r]
                    outputs = dict(zip(signals, row))
                    if name not in scorer.diagnosis:
                        scorer.diagnosis[name] = DiagnosisScore.of(
                            scorer.alarms[name], scorer.run.estimators[name], scorer.run.faults
                        )
                    scorer.diagnosis[name].add(k, outputs, scorer.active, scorer.segment)
        if bus is not None:
            self._bus(k, rows, bus)

    def forget(self, r: int) -> None:
        """Run r's scorer was fed otherwise (its tick's parts, ``Scorer.state`` ...): its active faults
        are compared afresh at its next tick here."""
        self._active[r] = None

    def _bus(self, k: int, rows: np.ndarray, bus: BusVerdicts) -> None:
        """The intrusion detector's and SecOC's scores of tick k, as ``Scorer._score`` scores them."""
        for r in rows.tolist():
            scorer = self.scorers[r]
            for rejection in bus.rejections[r]:
                scorer.bus.rejection(rejection)
            verdict = dict(zip(("any", *IDS_CHECKS), bus.ids[r].tolist())) if bus.ids is not None else None
            scorer.score_bus(k, verdict, {rejected_message(x) for x in bus.rejections[r]}, scorer.active)


def rejected_message(rejection: SecurityRejection) -> str:
    """What SecOC's score calls a rejected frame: its message, or its id where it is none of the run's."""
    return str(rejection.message or hex(int(rejection.id)))


@dataclass
class BusVerdicts:
    """What the bus's own schemes said of one tick of K runs (a batch): the intrusion detector's
    verdicts, (K, 1 + checks) as ``DetectorRuns.verdicts`` gives them (None: no detector), and the
    frames SecOC rejected, per run."""

    ids: np.ndarray | None
    rejections: Sequence[Sequence[SecurityRejection]]
