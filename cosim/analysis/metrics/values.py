"""The metrics of a run as a typed value (``RunMetrics``) and its one JSON form.

``to_json`` is what ``cosim inspect --json`` prints and ``cosim.api.metrics`` returns: each
dataclass an object with its fields in order (docs/metrics.md defines them), except that a field
marked ``OMIT_NONE`` is left out where it is None (the bus's ``intrusion_detection``,
``secoc_detection`` and ``secoc_rejected`` exist only where the run had the detector, SecOC, or
SecOC dropped frames; a diagnosis
of the intrusion detector has no ``kind``). ``from_json`` reads that form back.

Times are in seconds (delays from the fault's onset), errors in the state's units, loads as
fractions; absent values are None (null).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, is_dataclass
from functools import cache
from typing import Any

#: A field left out of the JSON form where it is None.
OMIT_NONE = {"omit_none": True}
#: A number as the log's metadata gives it (an integer stays one in the JSON form).
Number = float | int


def to_json(value: Any) -> Any:
    """The JSON form of a metrics value (a dataclass, or mappings and lists of them)."""
    if is_dataclass(value) and not isinstance(value, type):
        return {
            f.name: to_json(item)
            for f in fields(value)
            if not ((item := getattr(value, f.name)) is None and f.metadata.get("omit_none"))
        }
    if isinstance(value, dict):
        return {key: to_json(item) for key, item in value.items()}
    if isinstance(value, list):
        return [to_json(item) for item in value]
    return value


@dataclass
class FaultSpan:
    """``faults.<label>``: a fault as the scenario gives it (kind, targets, window), and when the
    truth says it was first active (``onset``) and no longer (``cleared``), in s."""

    kind: str | None = None
    targets: list[str] = field(default_factory=list)
    start: Number | None = None
    end: Number | None = None
    onset: float | None = None
    cleared: float | None = None


@dataclass
class FaultRecovery:
    """``estimators.<name>.faults.<label>``: the peak error in the fault's segment, when (s after
    the onset), and the time until the error stayed in the band (None: never)."""

    peak_error: float | None = None
    peak_at: float | None = None
    recovery_time: float | None = None
    recovered: bool = False


@dataclass
class Saturation:
    """``estimators.<name>.saturated.<signal>``: ticks at which the estimate signal sat at its bus
    range's bound (the node saturated it), and the first one's time (s)."""

    ticks: int = 0
    first_at: float | None = None


@dataclass
class EstimationMetrics:
    """``estimators.<name>``: the error |x − x̂| of one estimator."""

    kind: str | None = None
    kind_name: str | None = field(default=None, metadata=OMIT_NONE)
    """The name its kind's class declares, where ``kind`` is a module path (a plugin's)."""
    rms_pre_fault: float | None = None
    rms_post_fault: float | None = None
    final_error: float | None = None
    ticks_scored: int = 0
    band: float | None = None
    bias_rejection_ratio: float | None = None
    saturated: dict[str, Saturation] = field(default_factory=dict)
    faults: dict[str, FaultRecovery] = field(default_factory=dict)
    failed: str | None = None
    """The estimator failed during the run (its step raised, its node died): at which tick and what
    it raised; its metrics cover the ticks before."""


@dataclass
class FaultDiagnosis:
    """``diagnosis.<name>.faults.<label>``: the fault's detection and isolation."""

    detected: bool = False
    detection_delay: float | None = None
    alarm_before_onset: bool = False
    isolable: bool | None = None
    expected: list[str] | None = None
    isolation_delay: float | None = None
    isolated: list[str] | None = None
    isolation_correct: bool | None = None


@dataclass
class DiagnosisMetrics:
    """``diagnosis.<name>`` (and each check of ``bus.intrusion_detection``): false alarms, and per
    fault detection and isolation."""

    kind: str | None = field(default=None, metadata=OMIT_NONE)
    kind_name: str | None = field(default=None, metadata=OMIT_NONE)
    """The name its kind's class declares, where ``kind`` is a module path (a plugin's)."""
    isolation_flags: dict[str, list[str]] = field(default_factory=dict)
    ticks_scored: int = 0
    alarm_time_s: float = 0.0
    fault_free_time_s: float = 0.0
    false_alarms: int = 0
    false_alarm_rate_per_hour: float | None = None
    missed_detections: int = 0
    faults: dict[str, FaultDiagnosis] = field(default_factory=dict)


@dataclass
class IdTraffic:
    """``bus.by_id.<id>``: an arbitration id's DBC message, its frames and their bits on the bus."""

    message: str | None = None
    frames: int = 0
    bits: int = 0


@dataclass
class ForeignTraffic:
    """``bus.foreign``: what arrived that does not belong to the run, counted."""

    datagrams: int = 0
    frames: int = 0
    by_reason: dict[str, int] = field(default_factory=dict)


@dataclass
class LoadOverTime:
    """``bus.load_over_time``: the load per window of simulated time; on an arbitrated bus also the
    load the senders offered (which may pass 100 %)."""

    window_s: float = 1.0
    load: list[float] = field(default_factory=list)
    peak: float = 0.0
    offered: list[float] | None = field(default=None, metadata=OMIT_NONE)
    offered_peak: float | None = field(default=None, metadata=OMIT_NONE)


@dataclass
class IdLatency:
    """``bus.latency.<id>``: on an arbitrated bus, queueing to delivery (s) and what went wrong."""

    frames: int = 0
    min: float | None = None
    median: float | None = None
    max: float | None = None
    late: int = 0
    dropped: int = 0


@dataclass
class BusMetrics:
    """``bus``: frames, bits and load, losses and misses, what did not belong (docs/metrics.md)."""

    fd: bool | None = None
    bitrate: Number | None = None
    data_bitrate: Number | None = None
    frames: int = 0
    by_id: dict[str, IdTraffic] = field(default_factory=dict)
    load: float | None = None
    load_worst_case: float | None = None
    peak_tick_load: float | None = None
    lost: int | None = None
    lost_by_sender: dict[str, int] = field(default_factory=dict)
    late_by_sender: dict[str, int] = field(default_factory=dict)
    deadline_misses: int | None = None
    deadline_misses_by_node: dict[str, int] = field(default_factory=dict)
    foreign: ForeignTraffic = field(default_factory=ForeignTraffic)
    foreign_frames: dict[str, int] = field(default_factory=dict)
    intrusion_detection: dict[str, DiagnosisMetrics] | None = field(default=None, metadata=OMIT_NONE)
    secoc_detection: DiagnosisMetrics | None = field(default=None, metadata=OMIT_NONE)
    secoc_rejected: dict[str, dict[str, int]] | None = field(default=None, metadata=OMIT_NONE)
    load_over_time: LoadOverTime | None = None
    latency: dict[str, IdLatency] | None = None


@dataclass
class FrameCounts:
    """``frames``: on the bus, and lost."""

    total: int = 0
    lost: int | None = None


@dataclass
class RunMetrics:
    """The metrics of one log (``cosim inspect --json``'s object)."""

    file: str = ""
    scenario: str | None = None
    source: str | None = None
    seed: int | None = None
    status: str = "incomplete"
    contested_ticks: int = 0
    """Ticks during which another program sent on the runner's own ids (without authentication a
    receiver cannot tell its frames from the runner's): their estimates may rest on forged readings."""
    sample_time: Number | None = None
    ticks: int = 0
    duration_s: float | None = None
    time_span_s: float | None = None
    channels: dict[str, int] = field(default_factory=dict)
    frames: FrameCounts = field(default_factory=FrameCounts)
    fault_onset: Number | None = None
    faults: dict[str, FaultSpan] = field(default_factory=dict)
    error_unit: str | None = None
    """The unit of the estimation error |x − x̂| (the states' common unit, or the units it mixes)."""
    estimators: dict[str, EstimationMetrics] = field(default_factory=dict)
    baseline: str | None = None
    diagnosis: dict[str, DiagnosisMetrics] = field(default_factory=dict)
    bus: BusMetrics | None = None
    missing: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return to_json(self)

    @classmethod
    def from_json(cls, value: dict[str, Any]) -> RunMetrics:
        """The value of a JSON form (``to_json``'s, or ``cosim inspect --json``'s output); a field it
        lacks takes its default."""
        return _adapter().validate_python(value)


@cache
def _adapter() -> Any:  # pydantic.TypeAdapter[RunMetrics]
    from pydantic import TypeAdapter

    return TypeAdapter(RunMetrics)
