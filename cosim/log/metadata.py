"""The metadata records of a run log, each spelled once: what they hold, how they are written and read.

An MCAP metadata record is a flat map of strings; cosim writes these (nested values as JSON):

- ``cosim.run`` (``RunRecord``): the scenario's name, seed, timing, plant, signal names, each
  estimator (kind, messages, parameters with its design, design model, diagnostics), the controller,
  the faults, the bus and the wall-clock start, written before tick 0;
- ``cosim.scenario`` (``ScenarioRecord``): the TOML as given and the validated scenario as JSON;
- ``cosim.versions``: the versions of Python, cosim and the libraries that shape a log;
- ``cosim.bus``: where the run's bus was (``cosim.bus.transport.BusConfig``);
- ``cosim.result`` (``ResultRecord``): how the run ended, written last;
- ``cosim.replay`` (``ReplayRecord``): in a replay's log, what was replayed;
- ``cosim.import`` (``ImportRecord``): in a log ``cosim import`` made of another tool's CAN log,
  what it was made of and what it holds.

Reading is lenient: ``LogMetadata.read`` takes whatever a log has, and a field that is missing or
damaged gets its default and a warning, so that a reader of a damaged or foreign log reports what
it can instead of failing.
"""

from __future__ import annotations

import functools
import importlib.metadata
import json
import math
import platform
from dataclasses import dataclass, field, replace
from typing import Any, overload

from cosim import __version__
from cosim.bus.log_clock import CLOCKS, UNKNOWN, UTC
from cosim.errors import LogError
from cosim.log.reader import LogReader
from cosim.log.topics import decoded_topics

RUN, SCENARIO, VERSIONS, BUS, RESULT, REPLAY, IMPORT = (
    "cosim.run",
    "cosim.scenario",
    "cosim.versions",
    "cosim.bus",
    "cosim.result",
    "cosim.replay",
    "cosim.import",
)
#: The attachment holding the run's CAN database.
DBC_ATTACHMENT = "cosim.dbc"


@overload
def logged_dbc(reader: LogReader) -> str: ...
@overload
def logged_dbc(reader: LogReader, missing_ok: bool) -> str | None: ...


def logged_dbc(reader: LogReader, missing_ok: bool = False) -> str | None:
    """The run's CAN database, as its log holds it; LogError in one line if it is damaged, or
    missing (None instead with ``missing_ok``)."""
    data = reader.attachments().get(DBC_ATTACHMENT)
    if data is None:
        damage = [warning for warning in reader.warnings if DBC_ATTACHMENT in warning]
        if missing_ok and not damage:
            return None
        why = damage[-1] if damage else f"it has no {DBC_ATTACHMENT} attachment (a log cosim did not write?)"
        raise LogError(f"{reader.path}: cannot read the run's CAN database: {why}")
    try:
        return data.decode()
    except UnicodeDecodeError as error:
        raise LogError(f"{reader.path}: the {DBC_ATTACHMENT} attachment is not a DBC text ({error.reason})") from None


_LIBRARIES = ("mujoco", "numpy", "scipy", "python-can", "cantools", "mcap")


def versions() -> dict[str, str]:
    """The ``cosim.versions`` record of this process."""
    return dict(_versions())


@functools.cache  # the installed packages' metadata is read once a process (4 ms a package)
def _versions() -> dict[str, str]:
    found = {"python": platform.python_version(), "cosim": __version__}
    for package in _LIBRARIES:
        try:
            found[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            found[package] = "unknown"
    return found


class _Fields:
    """Typed reads of one record's string fields; a damaged field gives its default and a warning."""

    def __init__(self, record: dict[str, str], name: str, warnings: list[str]) -> None:
        self.record, self.name, self.warnings = record, name, warnings

    def text(self, key: str, default: str = "") -> str:
        return self.record.get(key, default)

    def json(self, key: str, default: Any) -> Any:
        if key not in self.record:
            return default
        try:
            value = json.loads(self.record[key])
        except ValueError:
            value = ValueError
        if value is ValueError or (isinstance(default, (list, dict)) and not isinstance(value, type(default))):
            self.warnings.append(f"{self.name} metadata field {key!r} is not valid JSON of the expected shape; ignored")
            return default
        return value

    def integer(self, key: str) -> int | None:
        try:
            return int(self.record[key]) if key in self.record else None
        except ValueError:
            self.warnings.append(f"{self.name} metadata field {key!r} is not an integer; ignored")
            return None

    def positive(self, key: str) -> float | None:
        try:
            value = float(self.record[key]) if key in self.record else None
        except ValueError:
            self.warnings.append(f"{self.name} metadata field {key!r} is not a number; ignored")
            return None
        return value if value and math.isfinite(value) and value > 0 else None


@dataclass(frozen=True)
class DiagnosticRecord:
    """What a diagnostic signal of an estimator is (``estimators.Diagnostic``): its kind (``alarm``,
    ``residual``, ...), what it refers to (a sensor, a thruster, ...) and its unit."""

    kind: str = ""
    target: str = ""
    unit: str = ""


def _diagnostics_json(diagnostics: dict[str, DiagnosticRecord]) -> dict[str, Any]:
    return {name: {"kind": d.kind, "target": d.target, "unit": d.unit} for name, d in diagnostics.items()}


def _diagnostics_from(value: Any) -> dict[str, DiagnosticRecord]:
    if not isinstance(value, dict):
        return {}
    return {
        str(name): DiagnosticRecord(**{k: str(v) for k, v in d.items() if k in ("kind", "target", "unit")})
        for name, d in value.items()
        if isinstance(d, dict)
    }


@dataclass(frozen=True)
class EstimatorRecord:
    """One estimator of the run: kind, its messages, the states it estimates, its parameters (those
    given and its design), its design model (``LinearModel.to_dict``) and its diagnostics by signal."""

    kind: str
    messages: list[str] = field(default_factory=list)
    states: list[str] = field(default_factory=list)
    params: dict[str, Any] = field(default_factory=dict)
    model: dict[str, Any] | None = None
    diagnostics: dict[str, DiagnosticRecord] = field(default_factory=dict)
    isolates: dict[str, list[str]] = field(default_factory=dict)
    """What each isolation diagnostic names as faulty: sensor or actuator names."""
    declared: str = ""
    """The name its kind's class declares, where ``kind`` is a module path (a plugin's
    ``package.module:Class`` or ``file.py:Class``); empty where ``kind`` is that name."""

    @property
    def kind_name(self) -> str:
        """The kind as people name it: the name its class declares."""
        return self.declared or self.kind

    def to_json(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            **({"declared": self.declared} if self.declared else {}),
            "messages": self.messages,
            "states": self.states,
            "params": self.params,
            "model": self.model,
            "diagnostics": _diagnostics_json(self.diagnostics),
            "isolates": self.isolates,
        }

    @classmethod
    def from_json(cls, value: Any) -> EstimatorRecord:
        value = value if isinstance(value, dict) else {}
        params, isolates = value.get("params"), value.get("isolates")
        return cls(
            str(value.get("kind") or ""),
            list(value.get("messages") or []),
            list(value.get("states") or []),
            params if isinstance(params, dict) else {},
            value.get("model") if isinstance(value.get("model"), dict) else None,
            _diagnostics_from(value.get("diagnostics")),
            {str(k): [str(t) for t in v] for k, v in isolates.items() if isinstance(v, list)}
            if isinstance(isolates, dict)
            else {},
            str(value.get("declared") or ""),
        )

    def signals_of(self, kind: str) -> dict[str, str]:
        """The diagnostic signals of one kind, each with its target."""
        return {name: d.target for name, d in self.diagnostics.items() if d.kind == kind}


@dataclass(frozen=True)
class ControllerRecord:
    """The controller node of a closed-loop run: its kind, parameters, diagnosis node, its messages
    (commands, then its status) and its design model."""

    kind: str
    params: dict[str, Any] = field(default_factory=dict)
    diagnosis: str = ""
    messages: list[str] = field(default_factory=list)
    model: dict[str, Any] | None = None
    status_messages: list[str] = field(default_factory=list)
    diagnostics: dict[str, DiagnosticRecord] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "params": self.params,
            "diagnosis": self.diagnosis,
            "messages": self.messages,
            "model": self.model,
            "status_messages": self.status_messages,
            "diagnostics": _diagnostics_json(self.diagnostics),
        }

    def status_topics(self) -> list[str]:
        """The topics that carry its status messages."""
        return list(decoded_topics({"controller": self.status_messages}))

    def signals_of(self, kind: str) -> list[str]:
        """The status signals of one diagnostic kind."""
        return [name for name, d in self.diagnostics.items() if d.kind == kind]

    @classmethod
    def from_json(cls, value: Any) -> ControllerRecord | None:
        if not isinstance(value, dict):
            return None
        return cls(
            str(value.get("kind") or ""),
            value.get("params") or {},
            str(value.get("diagnosis") or ""),
            list(value.get("messages") or []),
            value.get("model"),
            list(value.get("status_messages") or []),
            _diagnostics_from(value.get("diagnostics")),
        )


@dataclass(frozen=True)
class FaultRecord:
    """A fault of the run: its label, kind, window (``end`` None: until the end of the run) and the
    sensors or actuators it acts on (None where a log does not say)."""

    label: str
    kind: str | None = None
    start: float | None = None
    end: float | None = None
    targets: list[str] | None = None

    def to_json(self) -> dict[str, Any]:
        return {"label": self.label, "kind": self.kind, "start": self.start, "end": self.end, "targets": self.targets}


@dataclass(frozen=True)
class RunRecord:
    """``cosim.run``: what a reader of the log needs to know about the run, written before tick 0."""

    scenario: str | None = None
    source: str | None = None
    seed: int | None = None
    sample_time: float | None = None
    duration: float | None = None
    ticks: int | None = None
    plant: str | None = None
    states: list[str] = field(default_factory=list)
    sensors: list[str] = field(default_factory=list)
    actuators: list[str] = field(default_factory=list)
    disturbances: list[str] = field(default_factory=list)
    estimators: dict[str, EstimatorRecord] = field(default_factory=dict)
    model: dict[str, Any] | None = None
    continuous_model: dict[str, Any] | None = None
    clients: dict[str, Any] = field(default_factory=dict)
    controller: ControllerRecord | None = None
    fault_onset: float | None = None
    fault_onset_tick: int | None = None
    faults: list[FaultRecord] = field(default_factory=list)
    bus: dict[str, Any] = field(default_factory=dict)
    """interface, fd, bitrate, data_bitrate"""
    timing: dict[str, Any] = field(default_factory=dict)
    """mode, speed, node_timeout, join_timeout"""
    start_time_ns: int | None = None
    """When the run started (its log was opened), wall clock, UTC, in ns since the Unix epoch; None in
    logs older than this field. The one wall-clock value of a log: exports stamp frames at this
    start plus simulated time."""
    operating_point: str | None = None
    """Where the linear ``model`` was taken when the plant's operating point is no equilibrium of its
    inputs (``RunPlan.operating_point``); None (and not written) where it is one."""

    @property
    def dt_ns(self) -> int | None:
        """The sample time in nanoseconds (log time of tick k is k · dt_ns)."""
        return round(self.sample_time * 1e9) if self.sample_time else None

    def estimate_topics(self) -> dict[str, str]:
        """The topics that carry each estimator's messages → the estimator."""
        return decoded_topics({name: e.messages for name, e in self.estimators.items()})

    def to_metadata(self) -> dict[str, str]:
        return {
            "scenario": str(self.scenario),
            "source": str(self.source),
            "seed": str(self.seed),
            "sample_time": repr(self.sample_time),
            "duration": repr(self.duration),
            "ticks": str(self.ticks),
            "plant": str(self.plant),
            "states": json.dumps(self.states),
            "sensors": json.dumps(self.sensors),
            "actuators": json.dumps(self.actuators),
            "disturbances": json.dumps(self.disturbances),
            "estimators": json.dumps({name: e.to_json() for name, e in self.estimators.items()}),
            "model": json.dumps(self.model),
            "continuous_model": json.dumps(self.continuous_model),
            "clients": json.dumps(self.clients),
            "controller": json.dumps(None if self.controller is None else self.controller.to_json()),
            "fault_onset": json.dumps(self.fault_onset),
            "fault_onset_tick": json.dumps(self.fault_onset_tick),
            "faults": json.dumps([f.to_json() for f in self.faults]),
            "bus": json.dumps(self.bus),
            "timing": json.dumps(self.timing),
            "start_time_ns": json.dumps(self.start_time_ns),
            **({"operating_point": self.operating_point} if self.operating_point else {}),
        }

    @classmethod
    def from_metadata(cls, record: dict[str, str], warnings: list[str]) -> RunRecord:
        f = _Fields(record, RUN, warnings)
        faults = [
            FaultRecord(
                str(x.get("label")),
                x.get("kind"),
                x.get("start"),
                x.get("end"),
                [str(t) for t in x["targets"]] if isinstance(x.get("targets"), list) else None,
            )
            for x in f.json("faults", [])
            if isinstance(x, dict) and "label" in x
        ]
        onset_tick = f.json("fault_onset_tick", None)
        start = f.json("start_time_ns", None)
        return cls(
            scenario=record.get("scenario"),
            source=record.get("source"),
            seed=f.integer("seed"),
            sample_time=f.positive("sample_time"),
            duration=f.positive("duration"),
            ticks=f.integer("ticks"),
            plant=record.get("plant"),
            states=f.json("states", []),
            sensors=f.json("sensors", []),
            actuators=f.json("actuators", []),
            disturbances=f.json("disturbances", []),
            estimators={str(name): EstimatorRecord.from_json(e) for name, e in f.json("estimators", {}).items()},
            model=f.json("model", None),
            continuous_model=f.json("continuous_model", None),
            clients=f.json("clients", {}),
            controller=ControllerRecord.from_json(f.json("controller", None)),
            fault_onset=f.json("fault_onset", None),
            fault_onset_tick=onset_tick if isinstance(onset_tick, int) else None,
            faults=faults,
            bus=f.json("bus", {}),
            timing=f.json("timing", {}),
            start_time_ns=start if isinstance(start, int) and not isinstance(start, bool) else None,
            operating_point=record.get("operating_point") or None,
        )

    def with_only(self, name: str, estimator: EstimatorRecord) -> RunRecord:
        """The same run with ``estimator`` as its only estimator and no clients (a replay's record)."""
        return replace(self, estimators={name: estimator}, clients={})


@dataclass(frozen=True)
class ScenarioRecord:
    """``cosim.scenario``: the scenario file as given, the settings applied to it from outside the
    file (``--set``: a JSON list of [path, value]) and the validated scenario as JSON."""

    source: str = ""
    toml: str = ""
    resolved: str = ""
    settings: str = "[]"

    def to_metadata(self) -> dict[str, str]:
        return {"source": self.source, "toml": self.toml, "resolved": self.resolved, "settings": self.settings}

    def resolved_json(self, warnings: list[str] | None = None) -> dict[str, Any]:
        """The validated scenario as plain values ({} where the record has none or it is damaged)."""
        return _Fields(
            {"resolved": self.resolved} if self.resolved else {}, SCENARIO, [] if warnings is None else warnings
        ).json("resolved", {})


@dataclass(frozen=True)
class SenderCounts:
    """Frames of one node the runner received, of its data frames those lost (never received) and
    late (received after the tick they carry was over: realtime), and of the runner's frames it
    reported missing."""

    frames: int = 0
    lost: int = 0
    runner_frames_missed: int = 0
    late: int = 0


@dataclass(frozen=True)
class ResultRecord:
    """``cosim.result``: how the run ended, written when the log is closed."""

    status: str
    ticks: int | None = None
    frames_total: int | None = None
    frames_lost: int | None = None
    deadline_misses: int | None = None
    error: str = ""
    senders: dict[str, SenderCounts] = field(default_factory=dict)
    foreign: dict[str, int] = field(default_factory=dict)
    """What arrived that does not belong to the run: ``datagrams`` (not frames of the bus: garbage,
    another host's) and ``frames`` (frames the run did not send on its own ids), counted."""
    failed: dict[str, str] = field(default_factory=dict)
    """Estimator nodes that failed during the run (their step raised, their process died), each with
    the tick and what it raised; the run went on without them."""
    late_ticks: int = 0
    """Realtime: the ticks that started late (by a period or 20 ms or more: the run fell behind)."""
    contested_ticks: int = 0
    """Ticks during which a frame came on the runner's own ids that the runner did not send."""
    kernel_dropped: int = 0
    """Datagrams the kernel dropped before the runner read them (its receive buffer was full)."""

    def to_metadata(self) -> dict[str, str]:
        known = {key: getattr(self, key) for key in ("ticks", "frames_total", "frames_lost", "deadline_misses")}
        return {
            "status": self.status,
            # a count not known (a batched run builds no frames) is left out: read back as None, as written
            **{key: str(value) for key, value in known.items() if value is not None},
            "error": self.error,
            "senders": json.dumps({name: vars(counts) for name, counts in self.senders.items()}),
            "foreign": json.dumps(self.foreign),
            **({"failed": json.dumps(self.failed)} if self.failed else {}),  # logs without them as before
            **({"late_ticks": str(self.late_ticks)} if self.late_ticks else {}),
            **({"contested_ticks": str(self.contested_ticks)} if self.contested_ticks else {}),
            **({"kernel_dropped": str(self.kernel_dropped)} if self.kernel_dropped else {}),
        }

    @classmethod
    def from_metadata(cls, record: dict[str, str], warnings: list[str]) -> ResultRecord:
        f = _Fields(record, RESULT, warnings)
        senders = {}
        for name, counts in f.json("senders", {}).items():
            if isinstance(counts, dict):
                try:
                    senders[str(name)] = SenderCounts(
                        *(int(counts.get(k, 0)) for k in ("frames", "lost", "runner_frames_missed", "late"))
                    )
                except (TypeError, ValueError):
                    warnings.append(f"{RESULT} metadata field 'senders' has a damaged entry for {name!r}; ignored")
        return cls(
            record.get("status", "incomplete"),
            f.integer("ticks"),
            f.integer("frames_total"),
            f.integer("frames_lost"),
            f.integer("deadline_misses"),
            record.get("error", ""),
            senders,
            {str(k): int(v) for k, v in f.json("foreign", {}).items() if isinstance(v, int)},
            {str(k): str(v) for k, v in f.json("failed", {}).items()},
            f.integer("late_ticks") or 0,
            f.integer("contested_ticks") or 0,
            f.integer("kernel_dropped") or 0,
        )


@dataclass(frozen=True)
class ReplayRecord:
    """``cosim.replay``: the log replayed, the estimator fed with it and what was changed."""

    log: str
    estimator: str
    kind: str
    new: bool = False
    params: dict[str, Any] = field(default_factory=dict)
    ticks: int = 0

    def to_metadata(self) -> dict[str, str]:
        return {
            "log": self.log,
            "estimator": self.estimator,
            "kind": self.kind,
            "new": json.dumps(self.new),
            "params": json.dumps(self.params),
            "ticks": str(self.ticks),
        }

    @classmethod
    def from_metadata(cls, record: dict[str, str], warnings: list[str]) -> ReplayRecord:
        f = _Fields(record, REPLAY, warnings)
        return cls(
            record.get("log", ""),
            record.get("estimator", ""),
            record.get("kind", ""),
            bool(f.json("new", False)),
            f.json("params", {}),
            f.integer("ticks") or 0,
        )


@dataclass(frozen=True)
class ImportRecord:
    """``cosim.import``: the CAN log and DBC an imported log was made of, and its frames: how many,
    how many decoded, how many on ids the DBC does not describe (``unknown``) or not decodable by
    their message (``undecodable``), error and remote frames left out (``skipped``), and the time
    of its first and last frame (ns since the Unix epoch, as its messages' log times) and the zone
    they are in (``time_zone``, ``cosim.bus.log_clock``: UTC, an IANA zone, ``unknown`` for a local
    time logged as if UTC, ``none`` for a log with no date); with ``--channel``, the ``channel``
    imported and the frames of the log's other channels left out."""

    source: str
    format: str
    dbc: str
    frames: int = 0
    decoded: int = 0
    unknown: int = 0
    undecodable: int = 0
    skipped: int = 0
    start_time_ns: int | None = None
    end_time_ns: int | None = None
    channel: str = ""
    other_channels: int = 0
    time_zone: str = UNKNOWN

    def to_metadata(self) -> dict[str, str]:
        return {key: "" if value is None else str(value) for key, value in vars(self).items()}

    @classmethod
    def from_metadata(cls, record: dict[str, str], warnings: list[str]) -> ImportRecord:
        f = _Fields(record, IMPORT, warnings)
        frames, decoded, unknown, undecodable, skipped, others = (
            f.integer(key) or 0 for key in ("frames", "decoded", "unknown", "undecodable", "skipped", "other_channels")
        )
        start, end = (f.integer(key) if record.get(key) else None for key in ("start_time_ns", "end_time_ns"))
        text = {key: record.get(key, "") for key in ("source", "format", "dbc", "channel")}
        return cls(
            **text,
            # an import older than the field: UTC where its format records UTC (candump, MF4), else unknown
            time_zone=record.get("time_zone") or (UTC if CLOCKS.get(text["format"]) == UTC else UNKNOWN),
            frames=frames,
            decoded=decoded,
            unknown=unknown,
            undecodable=undecodable,
            skipped=skipped,
            start_time_ns=start,
            end_time_ns=end,
            other_channels=others,
        )


@dataclass(frozen=True)
class LogMetadata:
    """Every cosim metadata record a log holds (None where it has none), and what was wrong with them."""

    run: RunRecord | None = None
    scenario: ScenarioRecord | None = None
    result: ResultRecord | None = None
    replay: ReplayRecord | None = None
    bus: dict[str, str] = field(default_factory=dict)
    versions: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    imported: ImportRecord | None = None

    @classmethod
    def read(cls, meta: dict[str, dict[str, str]]) -> LogMetadata:
        """The records of a log's metadata (``LogReader.metadata()``), read leniently."""
        warnings: list[str] = []
        run = RunRecord.from_metadata(meta[RUN], warnings) if RUN in meta else None
        fields = ("source", "toml", "resolved", "settings")
        scenario = (
            ScenarioRecord(**{k: v for k, v in meta[SCENARIO].items() if k in fields}) if SCENARIO in meta else None
        )
        result = ResultRecord.from_metadata(meta[RESULT], warnings) if RESULT in meta else None
        replay = ReplayRecord.from_metadata(meta[REPLAY], warnings) if REPLAY in meta else None
        imported = ImportRecord.from_metadata(meta[IMPORT], warnings) if IMPORT in meta else None
        bus, versions = dict(meta.get(BUS, {})), dict(meta.get(VERSIONS, {}))
        return cls(run, scenario, result, replay, bus, versions, warnings, imported)
