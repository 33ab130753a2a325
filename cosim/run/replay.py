"""Replay a run log: its bus traffic, tick by tick, into an estimator process, or onto a live bus.

``Replay`` feeds the frames the runner put on the bus (SYNC(k), then the sensor and command frames
of tick k, exactly as logged: a frame a dropout kept off the bus is not in the log and is not
replayed) to one estimator node, a ``cosim node`` process on a bus of its own, with the runner's
lockstep protocol: tick k+1 starts once the node's heartbeat has closed tick k. The plant is not
simulated again: the new log holds the original truth (``/truth/*``, message for message), the
replayed frames and what the estimator answered, and ``cosim.replay`` metadata naming the log and
the estimator replayed. The replay is a ``Run`` whose plant is the log: participants, waiting,
loss accounting and logging are the runner's own.

The estimator is either one of the run's, rebuilt from what the log records about it (kind,
parameters including its design, design model), which reproduces its logged frames bit for bit,
or with some parameters changed (``params``), or a new one (``kind``) designed on the linear model
the log records. Designs go through the design cache (``cosim.design_cache``).

``play`` sends every frame of a log onto a live bus at the times the log gives them (over
``speed``), like ``canplayer``: for external tools and clients listening on that bus. The log is
cosim's MCAP (a run's, a replay's, an imported one) or any CAN log python-can reads.
"""

from __future__ import annotations

import math
import time
import tomllib
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import can

import estimators
from cosim import design_cache
from cosim.bus.canlogs import LogReading, read_frames
from cosim.bus.codec import COMMAND, CONTROL, CONTROLLER, HEARTBEAT, OPERATIONAL, SENSOR, SYNC, Codec, Decoded
from cosim.bus.transport import BusConfig, allocate, open_bus
from cosim.errors import CosimError, LogError
from cosim.log.metadata import (
    DBC_ATTACHMENT,
    REPLAY,
    RUN,
    SCENARIO,
    VERSIONS,
    LogMetadata,
    ReplayRecord,
    RunRecord,
    ScenarioRecord,
    logged_dbc,
    versions,
)
from cosim.log.reader import LogReader
from cosim.log.recorder import FAULTS, FRAMES, INPUTS, SECURITY, SENSORS, STATE
from cosim.log.writer import McapLog, SinkLog
from cosim.run.interrupts import DeferredInterrupts
from cosim.run.loop import Execution, execute, start_participants
from cosim.run.node import NodeSpec
from cosim.run.outcome import Progress, RunResult
from cosim.run.plan import RunPlan, build_estimators, channel_units, design_warnings, estimator_record
from cosim.run.session import Session
from cosim.scenario import LoadedScenario, Scenario
from cosim.scenario.overrides import path_parts
from cosim.scenario.tables import loads_toml
from estimators import Estimator, LinearModel, ParameterError

#: The truth topics a replay copies from the original log.
TRUTH = (STATE, SENSORS, INPUTS, FAULTS)
#: The frames a replay sends again: the runner's, and in a closed loop the controller node's
#: (commands, status and the heartbeat that closes its tick, which the estimators wait for).
REPLAYED_ROLES = (SYNC, SENSOR, COMMAND, CONTROL)


@dataclass
class LoggedTick:
    """What the original log holds of tick k: the runner's frames in bus order, and the truth."""

    tick: int
    frames: list[can.Message] = field(default_factory=list)
    truth: list[tuple[str, int, dict[str, Any]]] = field(default_factory=list)


def frame_of(record: dict[str, Any]) -> can.Message:
    """The CAN frame a ``/can/frames`` record describes."""
    return can.Message(
        arbitration_id=record["id"],
        is_extended_id=record["extended"],
        is_fd=record["fd"],
        bitrate_switch=record["brs"],
        data=bytes.fromhex(record["data"]),
    )


def logged_ticks(reader: LogReader, codec: Codec) -> Iterator[LoggedTick]:
    """The ticks of a log in order, streamed: memory holds one tick whatever the log's length."""
    current: LoggedTick | None = None
    # SecOC: frames the run's receivers dropped are not replayed (a replay signs what it sends with
    # keys of its own); their rejection is logged before them, with their payload
    dropped: Counter[tuple[int, str]] = Counter()
    for topic, time_ns, message in reader.messages([FRAMES, SECURITY, *TRUTH]):
        k = message["tick"]
        if topic == SECURITY:
            dropped[(message["id"], message.get("data", ""))] += 1
            continue
        if topic == FRAMES and dropped[(message["id"], message["data"])] > 0:
            dropped[(message["id"], message["data"])] -= 1
            continue
        if topic == FRAMES and not _replayed(frame_of(message), codec):
            continue  # the estimators' answers, boot-up heartbeats, the final NMT stop, foreign frames
        if current is None or k > current.tick:
            if current is not None:
                yield current
            current = LoggedTick(k)
        elif k < current.tick:
            continue  # cannot happen in a log written by cosim run: a tick's own records are contiguous
        if topic == FRAMES:
            current.frames.append(frame_of(message))
        else:
            current.truth.append((topic, time_ns, message))
    if current is not None:
        yield current


def _replayed(frame: can.Message, codec: Codec) -> bool:
    spec = codec.spec_of(frame)
    if spec is None:
        return False
    if spec.role == HEARTBEAT:
        if spec.sender != CONTROLLER:
            return False
        decoded = codec.decode(frame)  # not None: the codec knows the frame's id
        return decoded is not None and decoded.values["state"] == OPERATIONAL
    return spec.role in REPLAYED_ROLES


def settings_as_params(
    settings: Iterable[tuple[str, Any]], original: Scenario, estimator: str, kind: str | None
) -> dict[str, Any]:
    """The run's ``--set`` paths a replay can honour, as the replayed estimator's parameters.

    A replay feeds the logged frames to one estimator: ``estimators[i].params.NAME`` of that
    estimator is ``--param NAME``; every other path (the plant, faults, noise, the bus, another
    estimator) would change what was sent, which only a new simulation can do.
    """
    params: dict[str, Any] = {}
    names = [e.name for e in original.estimators]
    for key, value in settings:
        parts = path_parts(key)
        if parts[0] != "estimators" or len(parts) < 2 or not isinstance(parts[1], int):
            raise CosimError(
                f"--set {key}: a replay feeds the logged frames to an estimator, so only the replayed estimator's "
                f"parameters can change (estimators[i].params.NAME); to change {parts[0]}, simulate again "
                f"with 'cosim run SCENARIO --set {key}=...'"
            )
        index = parts[1]
        if kind is not None or index >= len(names) or names[index] != estimator:
            which = (
                f"the run's estimators[{index}] is {names[index]}"
                if index < len(names)
                else f"the run has {len(names)} estimators"
            )
            target = f"a new estimator ({estimator})" if kind is not None else estimator
            raise CosimError(f"--set {key}: {which}, and the replay runs {target}; give its parameters with --param")
        if len(parts) != 4 or parts[2] != "params" or not isinstance(parts[3], str):
            raise CosimError(
                f"--set {key}: only estimators[{index}].params.NAME can change in a replay (a new kind is "
                f"--estimator NEWNAME --kind KIND)"
            )
        params[parts[3]] = value
    return params


def parse_params(items: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` pairs; VALUE is a TOML value (``0.5``, ``[0.8, 0.9]``, ``"text"``, ``true``), and
    any other text stands for itself."""
    params: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise CosimError(f"--param {item!r}: expected KEY=VALUE, e.g. --param measurement_std=0.002")
        try:
            params[key] = loads_toml(f"value = {text}")["value"]
        except tomllib.TOMLDecodeError:
            params[key] = text
    return params


class LogSource:
    """Ticks of a log: the frames the runner put on the bus, as logged, and the truth, copied."""

    def __init__(self, reader: LogReader, replay: Replay, out: McapLog | SinkLog) -> None:
        """The ticks ``reader`` holds of the log ``replay`` replays, decoded with the log's DBC
        and again with the replay's; the truth is copied into ``out``."""
        self.reader, self.codec, self.ticks, self.path = reader, replay.plan.codec, replay.ticks, replay.log
        self.closed_loop = replay.closed_loop
        self._ticks = logged_ticks(reader, replay.log_codec)
        self._truth = {topic: out.channel(topic, {}) for topic in TRUTH}  # their schemas: the recorder's
        self._out = out
        self._logged: LoggedTick | None = None

    def frames(self, k: int) -> list[tuple[can.Message, Decoded | None]]:
        logged = self._logged = next(self._ticks, None)
        if logged is None or logged.tick != k:
            damage = "; ".join(self.reader.warnings) or "the log holds no more ticks"
            raise CosimError(f"{self.path}: the log ends at tick {k} ({damage}); the replay stops there")
        decoded = [(frame, self.codec.decode(frame)) for frame in logged.frames]
        self._check_complete(k, decoded)
        return decoded

    def _check_complete(self, k: int, frames: list[tuple[can.Message, Decoded | None]]) -> None:
        """A tick the log holds only in part (cut, or a damaged chunk skipped) would leave the node
        waiting for frames that never come: it ends the replay, saying so."""
        sync = next((d for _, d in frames if d is not None and d.spec.role == SYNC), None)
        runner = sum(
            1
            for _, d in frames
            if d is not None and (d.spec.role == SENSOR or (d.spec.role == COMMAND and not self.closed_loop))
        )
        announced = None if sync is None else int(sync.values["frames"])
        problem = None
        if announced is None:
            problem = "it has no SYNC frame"
        elif runner != announced:
            problem = f"its SYNC announces {announced} frames and the log holds {runner}"
        elif self.closed_loop:
            beat = next(
                (d for _, d in frames if d is not None and d.spec.role == HEARTBEAT and d.spec.sender == CONTROLLER),
                None,
            )
            sent = sum(
                1
                for _, d in frames
                if d is not None and d.spec.sender == CONTROLLER and d.spec.role in (COMMAND, CONTROL)
            )
            if beat is None:
                problem = "the controller's heartbeat closing it is missing"
            elif int(beat.values["frames"]) != sent:
                problem = f"the controller announced {int(beat.values['frames'])} frames and the log holds {sent}"
        if problem is not None:
            damage = "; ".join(self.reader.warnings) or "the log is cut or damaged there"
            raise CosimError(f"{self.path}: the log ends at tick {k}: {problem} ({damage}); the replay stops before it")

    def advance(self, k: int, session: Session) -> None:
        assert self._logged is not None
        for topic, time_ns, payload in self._logged.truth:
            self._out.write(self._truth[topic], time_ns, payload)


class Replay(Execution):
    """One estimator fed with a log's bus traffic, into a new log.

    ``estimator`` names one of the run's estimators, or with ``kind`` a new one; ``params`` change
    (or, for a new one, give) its parameters. ``interface``, ``channel`` and ``port`` choose the
    replay's bus (default: a fresh host-local ``udp_multicast`` bus). The replay is the runner's
    session and tick loop over a ``LogSource``, with a plan that holds the one estimator.
    """

    def __init__(
        self,
        log: str | Path,
        out: str | Path,
        estimator: str,
        *,
        kind: str | None = None,
        params: dict[str, Any] | None = None,
        settings: Iterable[tuple[str, Any]] = (),
        interface: str | None = None,
        channel: str | None = None,
        port: int | None = None,
    ) -> None:
        self.log, self.out = Path(log), Path(out)
        if self.out.exists() and self.log.exists() and self.out.samefile(self.log):
            raise CosimError(f"--out {out}: that is the log being replayed; write the replay to another file")
        run, scenario_record, original = self._read_log()
        overrides = {**settings_as_params(settings, original, estimator, kind), **(params or {})}
        self.name, self.new = estimator, kind is not None
        if kind is not None:
            model, spec_params = self._new_design(estimator, kind, run, overrides)
        else:
            kind, model, spec_params = self._recorded_design(estimator, run, original, overrides)
        try:
            estimators.ESTIMATORS[kind].check_params(spec_params)
        except ParameterError as error:
            raise CosimError(f"--param {error}") from None
        self.kind, self.overrides, self.params = kind, overrides, spec_params
        scenario = original.with_overrides(
            estimators=[{"name": estimator, "kind": kind, "params": spec_params}],
            clients=[],
            mode="lockstep",
            interface=interface or "udp_multicast",
            channel=channel or "",
            port=port or 0,
        ).model_copy(update={"controller": None})  # a closed loop's controller is replayed from the log, not run
        built = self._build(scenario, model)
        self.plan = RunPlan(
            loaded=LoadedScenario(scenario, str(self.log), scenario_record.toml),
            scenario=scenario,
            state_names=tuple(run.states),
            model=model,
            continuous_model=None,
            estimators=built,
            controller=None,
            # The run's own DBC keeps a replayed estimator's ids, so that its frames can match bit for bit.
            codec=scenario.codec() if self.new else self.log_codec,
            warnings=tuple(design_warnings(scenario, built)),
            faults=tuple(run.faults),
            onset_tick=run.fault_onset_tick,
            units=channel_units(scenario),
        )

    def _build(self, scenario: Scenario, model: LinearModel) -> dict[str, Estimator]:
        """The replayed estimator: designed again when it is new or its parameters changed, else
        with the run's design (the parameters the log records carry it)."""
        if self.new or self.overrides:
            return build_estimators(scenario, model, f"{self.log} (replay)", model)
        try:
            return {self.name: design_cache.create(self.kind, model, self.params, scenario.sample_time)}
        except ParameterError as error:
            raise CosimError(f"{self.log}: estimator {self.name}: params.{error}") from None

    def _read_log(self) -> tuple[RunRecord, ScenarioRecord, Scenario]:
        """The log's run record, scenario record and scenario; its codec, ticks and attachments."""
        with LogReader(self.log) as reader:
            raw, self.attachments = reader.metadata(), reader.attachments()
            dbc = logged_dbc(reader, missing_ok=True)
            self.ticks = _sync_count(reader)
        self.meta = LogMetadata.read(raw)
        result, run, scenario_record = self.meta.result, self.meta.run, self.meta.scenario
        made = result.ticks if result is not None else (run.ticks if run else None)
        if made is not None and made > self.ticks:  # the log lacks ticks its run made: replayed up to there
            self.ticks = made
        if run is None or scenario_record is None or dbc is None:
            raise LogError(
                f"{self.log}: no cosim.run metadata, scenario or DBC; replay needs a log written by cosim run"
            )
        self.closed_loop = run.controller is not None
        if self.ticks == 0:
            raise LogError(f"{self.log}: the log has no tick (no SYNC frame): there is nothing to replay")
        try:
            original = Scenario.from_resolved(scenario_record.resolved)
        except ValueError as error:
            raise LogError(f"{self.log}: its scenario cannot be read by this version of cosim ({error})") from None
        self.log_codec = Codec.from_dbc(dbc)
        return run, scenario_record, original

    def _new_design(
        self, estimator: str, kind: str, run: RunRecord, params: dict[str, Any]
    ) -> tuple[LinearModel, dict[str, Any]]:
        """A new estimator's design model (the one the log records) and parameters."""
        if estimator in run.estimators:
            raise CosimError(
                f"--estimator {estimator}: the run already has an estimator of that name; drop --kind to "
                f"replay it, or give the new one another name"
            )
        if self.closed_loop:
            raise CosimError(
                f"--kind {kind}: a new estimator cannot join the replay of a closed-loop run (the "
                f"controller node's ids would move); replay one of the run's estimators"
            )
        if kind not in estimators.ESTIMATORS:
            raise CosimError(
                f"--kind {kind}: unknown estimator kind (known: {', '.join(sorted(estimators.ESTIMATORS))})"
            )
        return _recorded_model(run, estimators.ESTIMATORS[kind].continuous, kind, self.log), params

    def _recorded_design(
        self, estimator: str, run: RunRecord, original: Scenario, overrides: dict[str, Any]
    ) -> tuple[str, LinearModel, dict[str, Any]]:
        """One of the run's estimators: its kind, its design model and its parameters (changed ones
        mean a new design; unchanged ones come with the run's design)."""
        recorded = run.estimators
        if estimator not in recorded:
            raise CosimError(
                f"--estimator {estimator}: the run has no estimator of that name (it has: "
                f"{', '.join(recorded) or 'none'}); add --kind KIND to replay a new one"
            )
        design_model = recorded[estimator].model
        if design_model is None:
            raise LogError(
                f"{self.log}: the log does not record the design model of {estimator}; it cannot be replayed"
            )
        given = next((e.params for e in original.estimators if e.name == estimator), recorded[estimator].params)
        params = {**given, **overrides} if overrides else recorded[estimator].params
        return recorded[estimator].kind, LinearModel.from_dict(design_model), params

    def execute(
        self,
        on_progress: Callable[[Progress], None] | None = None,
        progress_every: float = 0.2,
        on_start: Callable[[Replay], None] | None = None,
    ) -> RunResult:
        """Replay every logged tick; the new log is complete and valid whatever ends the replay."""
        plan, s = self.plan, self.plan.scenario
        self.bus = bus = allocate(s.bus.interface, s.bus.channel, s.bus.port, s.bus.fd)
        with LogReader(self.log) as reader, plan.session(self.out, bus) as session:
            self.session = session
            self._write_metadata(session)
            session.begin_log(f"replay of {self.log} into {self.name} ({self.kind}), ticks={self.ticks}", plan.warnings)
            source = LogSource(reader, self, session.log)

            def start() -> None:
                start_participants(plan, session, self.node_spec)
                if on_start is not None:
                    on_start(self)

            return execute(source, session, start, [self.name], on_progress, progress_every)

    def node_spec(self, name: str, bus: BusConfig) -> NodeSpec:
        """The runner's node spec; in a closed loop the node reads the replayed controller's commands."""
        spec = self.plan.node_spec(name, bus)
        return replace(spec, upstream={CONTROLLER: 0}) if self.closed_loop else spec

    def _write_metadata(self, session: Session) -> None:
        """The original run's records, with this estimator as the run's only one, and ``cosim.replay``."""
        log, codec = session.log, self.plan.codec
        assert self.meta.run is not None and self.meta.scenario is not None
        record = estimator_record(codec, self.name, self.kind, self.params, self.plan.estimators[self.name])
        log.metadata(RUN, self.meta.run.with_only(self.name, record).to_metadata())
        log.metadata(SCENARIO, self.meta.scenario.to_metadata())
        log.metadata(VERSIONS, versions())
        log.metadata(
            REPLAY,
            ReplayRecord(str(self.log), self.name, self.kind, self.new, self.overrides, self.ticks).to_metadata(),
        )
        for name, data in self.attachments.items():
            if name != DBC_ATTACHMENT:
                log.attach(name, "application/xml" if name.endswith(".xml") else "application/octet-stream", data)
        log.attach(DBC_ATTACHMENT, "text/plain", codec.dbc.encode())


def _sync_count(reader: LogReader) -> int:
    """How many ticks the log has: its SYNC frames (from the summary's statistics when it has them)."""
    topic = "/can/SYNC"
    counts = reader.summary_counts()
    if counts is not None:
        return counts.get(topic, 0)
    return sum(1 for _ in reader.messages([topic]))


def _recorded_model(run: RunRecord, continuous: bool, kind: str, log: Path) -> LinearModel:
    """The plant's linear model as the log records it, in continuous or discrete time."""
    recorded = run.continuous_model if continuous else run.model
    if recorded is not None:
        return LinearModel.from_dict(recorded)
    for entry in run.estimators.values():  # the model an estimator of the run was designed on
        if entry.model is not None and (entry.model.get("dt") is None) == continuous:
            return LinearModel.from_dict(entry.model)
    time_domain = "continuous" if continuous else "discrete"
    raise CosimError(
        f"--kind {kind}: is designed on the {time_domain}-time model, which {log} does not record (none of its "
        f"estimators uses one); pick a kind working in the other time domain, or run the scenario with it"
    )


@dataclass(frozen=True)
class Playback:
    """What ``play`` sent: frames, the simulated time they span, and the wall time it took."""

    frames: int
    sim_time: float
    wall_time: float
    warnings: list[str]


def play(
    log: str | Path,
    interface: str = "udp_multicast",
    channel: str = "",
    port: int = 0,
    speed: float = 1.0,
    on_start: Callable[[BusConfig], None] | None = None,
) -> Playback:
    """Send every frame of ``log`` onto a bus (default: a fresh host-local ``udp_multicast`` one):
    the frame recorded t seconds after the log's first at t / ``speed`` seconds of wall-clock time
    after the start, in the log's order. ``log`` is an MCAP log (a run's, a replay's, an imported
    one: its ``/can/frames``) or any CAN log python-can reads (``cosim.bus.canlogs``: candump, BLF,
    ASC, TRC, MF4, ...), whose error frames are left out. ``on_start`` gets the bus before the
    first frame; Ctrl-C stops between frames."""
    if not (speed > 0 and math.isfinite(speed)):
        raise CosimError(f"--speed {speed:g}: must be a positive number of simulated seconds per wall-clock second")
    sent, sim_time, warnings = 0, 0.0, list[str]()
    with ExitStack() as stack:
        interrupts = stack.enter_context(DeferredInterrupts())
        source, fd = _recorded_frames(Path(log), stack, warnings)
        bus = allocate(interface, channel, port, fd)
        with open_bus(bus) as live:
            if on_start is not None:
                on_start(bus)
            start = first = None
            for time_ns, frame in source:
                first = time_ns if first is None else first
                sim_time = (time_ns - first) / 1e9
                if start is None:  # the clock starts with the first frame, once the reader has it
                    start = time.perf_counter()
                due = start + sim_time / speed
                while (wait := due - time.perf_counter()) > 0:
                    interrupts.check()
                    time.sleep(min(wait, 0.05))
                interrupts.check()
                live.send(frame)
                sent += 1
    return Playback(sent, sim_time, 0.0 if start is None else time.perf_counter() - start, warnings)


def _recorded_frames(
    log: Path, stack: ExitStack, warnings: list[str]
) -> tuple[Iterator[tuple[int, can.Message]], bool]:
    """The frames of a log with their times in ns, and whether the bus must carry CAN FD (a run's
    as its bus did; any other log's may hold FD frames). An MCAP log's reader's warnings join
    ``warnings`` once the frames are read."""
    if log.suffix.lower() != ".mcap":
        reading = LogReading()
        stack.callback(lambda: warnings.extend(reading.warnings))
        return ((t, f) for f, t in read_frames(log, reading) if not f.is_error_frame), True
    reader = stack.enter_context(LogReader(log))
    stack.callback(lambda: warnings.extend(reader.warnings))
    meta = LogMetadata.read(reader.metadata())
    if meta.run is None and meta.imported is None:
        raise LogError(f"{log}: no cosim.run or cosim.import metadata; --live plays the /can/frames of cosim's logs")
    fd = bool(meta.run.bus.get("fd", False)) if meta.run is not None else True
    return ((time_ns, frame_of(record)) for _, time_ns, record in reader.messages([FRAMES])), fd
