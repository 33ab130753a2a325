"""Detection and isolation by one diagnosis process, tick by tick (docs/metrics.md, "Detection and
isolation"): per fault the detection delay, the isolation delay and decision, and false alarms
(alarm episodes starting with no fault active) with their rate per fault-free hour.

A process is an estimator that publishes an ``alarm`` (raised when > 0.5) and optionally isolation
flags; the intrusion detector's checks are scored the same way, without flags, and SecOC's
rejections with a flag per authenticated message (a forged or replayed frame names its message).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from cosim.analysis.metrics.segments import Segment
from cosim.analysis.metrics.values import DiagnosisMetrics, FaultDiagnosis, FaultSpan
from cosim.log.metadata import EstimatorRecord
from estimators.base import DiagnosticKind


@dataclass
class _Open:
    """A fault's diagnosis while its segment lasts."""

    start: int
    alarm_before_onset: bool
    detected: int | None = None
    isolated: int | None = None
    decision: list[str] | None = None
    correct: bool | None = None
    wrong: bool = False


class DiagnosisScore:
    """Detection and isolation by one process: ``alarm`` its alarm signal, ``faults`` the run's,
    ``flags`` each isolation flag (what it isolates, e.g. a thruster T1) with its signal and the
    targets it names as faulty (none: the intrusion detector, which only detects)."""

    def __init__(
        self, alarm: str, faults: dict[str, FaultSpan], flags: Mapping[str, tuple[str, list[str]]] | None = None
    ) -> None:
        self.alarm = alarm
        self.run_faults = faults
        flags = dict(sorted((flags or {}).items()))
        self.signals = {flag: signal for flag, (signal, _) in flags.items()}
        self.flags = list(self.signals)
        self.targets = {flag: list(targets) for flag, (_, targets) in flags.items()}
        self.alarm_prev = False
        self.scored = 0
        self.fault_free_ticks = 0
        self.false_alarms = 0
        self.alarm_ticks = 0
        self.open: dict[str, _Open] = {}
        self.faults: dict[str, FaultDiagnosis] = {}

    @classmethod
    def of(cls, alarm: str, record: EstimatorRecord, faults: dict[str, FaultSpan]) -> DiagnosisScore:
        """An estimator's diagnosis: its isolation signals are its flags, named by what they isolate."""
        isolation = record.signals_of(DiagnosticKind.ISOLATION)
        flags = {target or signal: (signal, record.isolates.get(signal, [])) for signal, target in isolation.items()}
        return cls(alarm, faults, flags)

    def expected(self, label: str) -> set[str]:
        """The flags whose targets meet the targets of fault ``label``."""
        span = self.run_faults.get(label)
        targets = set(span.targets) if span else set()
        return {flag for flag, names in self.targets.items() if targets & set(names)}

    def add(self, k: int, outputs: dict[str, float], active: set[str], segment: Segment | None) -> None:
        """The process's outputs at tick ``k`` (its alarm and flags by signal)."""
        alarm = outputs[self.alarm] > 0.5
        raised = {
            flag
            for flag, signal in self.signals.items()
            if isinstance(v := outputs.get(signal), (int, float)) and v > 0.5
        }
        self.scored += 1
        self.alarm_ticks += alarm
        if not active:
            self.fault_free_ticks += 1
            self.false_alarms += alarm and not self.alarm_prev
        if segment is not None:
            for label in segment.labels:
                state = self.open.setdefault(label, _Open(segment.start, self.alarm_prev))
                if state.detected is None and alarm:
                    state.detected = k
                if state.isolated is None and raised:
                    # A fault is isolated once all its flags are up (a double fault's second thruster may
                    # be named later than the first); a flag no active fault explains, up to then, is wrong.
                    allowed = set().union(*(self.expected(g) for g in active))
                    state.wrong |= not raised <= allowed
                    if self.expected(label) <= raised:
                        state.isolated, state.decision = k, sorted(raised)
                        state.correct = not state.wrong
        self.alarm_prev = alarm

    def close(self, segment: Segment, dt: float) -> None:
        for label in segment.labels:
            state = self.open.pop(label, None)
            if state is None:  # no alarm value in the whole segment
                continue
            isolable = bool(self.expected(label))
            correct = state.correct
            if correct is None and isolable:
                correct = False  # never isolated
            flags = bool(self.flags)
            self.faults[label] = FaultDiagnosis(
                detected=state.detected is not None,
                detection_delay=segment.since(state.detected, dt),
                alarm_before_onset=state.alarm_before_onset,
                isolable=isolable if flags else None,
                expected=sorted(self.expected(label)) if flags else None,
                isolation_delay=segment.since(state.isolated, dt),
                isolated=state.decision,
                isolation_correct=correct if flags else None,
            )

    def metrics(self, dt: float, kind: str | None = None) -> DiagnosisMetrics:
        """The scores: false alarms (per hour of fault-free time), and per fault detection (delay,
        missed) and isolation; ``kind`` the estimator's (None for the intrusion detector)."""
        hours = self.fault_free_ticks * dt / 3600 if dt else 0.0
        return DiagnosisMetrics(
            kind=kind,
            isolation_flags=self.targets,
            ticks_scored=self.scored,
            alarm_time_s=round(self.alarm_ticks * dt, 9),
            fault_free_time_s=round(self.fault_free_ticks * dt, 9),
            false_alarms=self.false_alarms,
            false_alarm_rate_per_hour=self.false_alarms / hours if hours else None,
            missed_detections=sum(not fault.detected for fault in self.faults.values()),
            faults=self.faults,
        )
