"""The co-simulation runner: owns simulated time and drives one run tick by tick.

The plant runs here; every estimator runs as a node in a process of its own and talks to the
runner only through CAN frames on the run's bus (``cosim/bus.py``). Tick k at t_k = k τ:

  1. read the plant's true state x_k and sensors y_k (MuJoCo, after the previous mj_step);
  2. apply the fault layer to the readings; evaluate the commanded inputs (open loop);
  3. send SYNC(k), then the sensor and command frames of tick k; in a closed-loop run the
     ``controller`` node answers the sensor frames with the command frames of tick k, which the
     runner waits for (until tick k's deadline in ``realtime``, holding the last commands if late);
  4. collect what the nodes send back: in ``lockstep`` until every node's heartbeat closing tick
     k has arrived (a node that dies or hangs ends the run with its name, exit status and last
     output); in ``realtime`` until tick k's wall-clock deadline, counting missing heartbeats as
     deadline misses;
  5. log every frame and the ground truth of tick k;
  6. apply the commands as their frames carry them, through the actuator faults, hold them for τ
     and advance the physics (mj_step).

Frames of one tick are logged in a canonical order: the runner's own frames as sent, then the
frames received during the tick by arbitration id (lowest first, as a CAN bus arbitrates frames
pending together); the wall-clock arrival order of UDP datagrams from several processes is not
deterministic, this order is. Whatever ends the run, the nodes are stopped (NMT stop) and the MCAP
log is finished with how the run ended.
"""

from __future__ import annotations

import importlib.metadata
import json
import math
import platform
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from uuid import uuid4

import can
import numpy as np

import estimators
import faults as fm
from cosim import __version__
from cosim.run import design_cache
from cosim.bus.transport import BusConfig, allocate, open_bus
from cosim.bus.codec import (
    BOOTUP, CLIENT, COMMAND, CONTROL, CONTROLLER, ESTIMATE, HEARTBEAT, NMT_STOP, OPERATIONAL, PLANT, RUNNER, STOPPED, Codec,
    Decoded,
)
from cosim.errors import CodecError, CosimError, ModelError, ScenarioError
from cosim.run.interrupts import DeferredInterrupts
from cosim.run.launcher import ExternalClient, LocalController, LocalNode, Participant, ProcessNode
from cosim.log.mcapfile import McapLog
from cosim.run.node import NodeSpec, model_to_dict
from cosim.plant.physics import Plant
from cosim.log.recorder import RunRecorder
from cosim.bus.registry import Registration
from cosim.scenario import ActuatorEffectivenessSpec, ActuatorOffsetSpec, LoadedScenario, Scenario, build_waveform
from cosim.plant.statespace import StateSpacePlant
from estimators import Estimator, LinearModel, ParameterError
from estimators import controller as controllers
from estimators.design import fault_rejectable

OWN_SENDERS = (RUNNER, PLANT, CONTROLLER)
_POLL = 0.05  # s: how often a waiting runner checks for Ctrl-C and dead nodes
_ENVIRONMENT = 0xE1  # spawn key of the disturbance models' random streams (the faults use others)


class NodeFailure(CosimError):
    """A node or client died, hung or left during the run."""


@dataclass(frozen=True)
class Progress:
    tick: int
    ticks: int
    sim_time: float
    wall_time: float
    frames: int
    deadline_misses: int = 0

    @property
    def realtime_factor(self) -> float:
        return self.sim_time / self.wall_time if self.wall_time > 0 else float("inf")


@dataclass(frozen=True)
class RunResult:
    path: Path
    status: str
    ticks: int
    frames: int
    frames_lost: int
    wall_time: float
    sim_time: float
    error: str = ""
    deadline_misses: int = 0
    senders: dict = field(default_factory=dict)
    startup_time: float = 0.0
    """Wall time from the start until every node had joined."""
    loop_time: float = 0.0
    """Wall time of the ticks themselves (from tick 0 to the end of the last one)."""

    @property
    def realtime_factor(self) -> float:
        return self.sim_time / self.wall_time if self.wall_time > 0 else float("inf")


def build_faults(s: Scenario) -> fm.FaultInjector:
    """The scenario's noise and faults as fault models on the transmitted sensors and actuators."""
    sensors, actuators = list(s.sensors), list(s.actuators)

    def sensor_model(spec, label: str) -> fm.SensorFault:
        names = spec.sensors if spec.sensors is not None else sensors
        channels = tuple(sensors.index(n) for n in names)
        common = dict(channels=channels, start=spec.start, end=spec.end, label=label)
        n = len(channels)
        widen = lambda values: tuple(values) * n if len(values) == 1 else tuple(values)  # noqa: E731
        match spec.kind:
            case "bias":
                return fm.Bias(**common, value=widen(spec.value), amplitude=build_waveform(spec.amplitude))
            case "drift":
                return fm.Drift(**common, rate=widen(spec.rate))
            case "gain":
                return fm.Gain(**common, gain=widen(tuple(build_waveform(g) for g in spec.gain)))
            case "gaussian_noise":
                return fm.GaussianNoise(**common, std=widen(spec.std))
            case "uniform_noise":
                return fm.UniformNoise(**common, bound=widen(spec.bound))
            case "stuck":
                return fm.StuckAt(**common, value=None if spec.value is None else widen(spec.value))
            case "dropout":
                return fm.Dropout(**common, probability=spec.probability)
            case "outliers":
                return fm.Outliers(**common, probability=spec.probability, magnitude=widen(spec.magnitude))
        raise AssertionError(spec.kind)

    noise_labels, fault_labels = s.fault_labels()
    noise = [sensor_model(spec, label) for spec, label in zip(s.noise, noise_labels)]
    sensor_faults, actuator_faults = [], []
    for spec, label in zip(s.faults, fault_labels):
        if isinstance(spec, ActuatorEffectivenessSpec):
            names = spec.actuators if spec.actuators is not None else actuators
            profiles = tuple(build_waveform(w) for w in spec.effectiveness)
            profiles = profiles * len(names) if len(profiles) == 1 else profiles
            actuator_faults.append(fm.ActuatorEffectiveness(
                channels=tuple(actuators.index(n) for n in names), start=spec.start, end=spec.end, label=label,
                effectiveness=profiles,
            ))
        elif isinstance(spec, ActuatorOffsetSpec):
            names = spec.actuators if spec.actuators is not None else actuators
            values = tuple(spec.value) * len(names) if len(spec.value) == 1 else tuple(spec.value)
            actuator_faults.append(fm.ActuatorOffset(
                channels=tuple(actuators.index(n) for n in names), start=spec.start, end=spec.end, label=label,
                value=values, amplitude=build_waveform(spec.amplitude),
            ))
        else:
            sensor_faults.append(sensor_model(spec, label))
    return fm.FaultInjector(noise, sensor_faults, actuator_faults, s.seed)


def build_estimators(s: Scenario, model: LinearModel, source: str, continuous: LinearModel | None = None) -> dict[str, Estimator]:
    """Each estimator of the scenario, designed on ``model`` (discrete time), or on ``continuous``
    (the continuous-time linearization) for the kinds that integrate their own ODE."""
    built = {}
    for i, spec in enumerate(s.estimators):
        try:
            chosen = continuous if estimators.ESTIMATORS[spec.kind].continuous else model
            if chosen is None:
                raise ParameterError("model", f"{spec.kind} needs the continuous-time model")
            cached = design_cache.load(spec.kind, spec.params, chosen)
            built[spec.name] = estimators.create(spec.kind, chosen, {**spec.params, **(cached or {})}, s.sample_time)
            if cached is None:
                design_cache.store(spec.kind, spec.params, chosen, built[spec.name].design_params())
        except ParameterError as error:
            raise ScenarioError(f"{source}: estimators[{i}] ({spec.name}): params.{error}") from None
    return built


def ending(exc: BaseException) -> tuple[str, str]:
    """The status and error a log records for what stopped a run: Ctrl-C or SIGTERM (interrupted),
    a CosimError (its message) or anything else (its type and message)."""
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted", ""
    if isinstance(exc, CosimError):
        return "error", str(exc)
    return "error", f"{type(exc).__name__}: {exc}"


def build_controller(s: Scenario, model: LinearModel, source: str, continuous: LinearModel | None = None) -> controllers.Controller | None:
    """The scenario's controller on the plant's linear model, with its parameters checked."""
    if s.controller is None:
        return None
    kind = controllers.CONTROLLERS[s.controller.kind]
    try:
        return kind.from_params(continuous if kind.continuous else model, s.controller.params, s.sample_time)
    except ParameterError as error:
        raise ScenarioError(f"{source}: controller.params.{error}") from None


def design_warnings(s: Scenario, built: dict[str, Estimator]) -> list[str]:
    """Warnings about scenario faults that an estimator cannot reject by design: a constant bias
    whose direction lies in Im(Y) (TAC 2024 Remark 4, CDC 2016 Remark 2)."""
    found = []
    for spec in s.faults:
        if spec.kind != "bias":
            continue
        sensors = spec.sensors if spec.sensors is not None else list(s.sensors)
        values = np.broadcast_to(np.asarray(spec.value, dtype=float), (len(sensors),))
        for name, estimator in built.items():
            Y = getattr(estimator, "Y", None)
            if Y is None:  # not an output-allocation observer
                continue
            phi = np.zeros(estimator.model.p)
            for sensor, value in zip(sensors, values):
                if sensor in estimator.model.outputs:
                    phi[estimator.model.outputs.index(sensor)] = value
            sigma = getattr(estimator, "Sigma", np.eye(len(phi)))
            if not fault_rejectable(Y, sigma @ phi):
                found.append(f"estimator {name}: the bias {spec.name or 'fault'} {np.round(phi, 6).tolist()} lies in Im(Y), so no "
                             "choice of pseudoinverse weights can reject it (TAC 2024 Remark 4)")
    return found


def first_tick_at(s: Scenario, start: float) -> int:
    """The first tick k with t_k >= start: where a fault starting at ``start`` is first active."""
    k = max(0, math.ceil(start / s.sample_time) - 1)
    while s.time(k) < start:
        k += 1
    return k


def versions() -> dict[str, str]:
    found = {"python": platform.python_version(), "cosim": __version__}
    for package in ("mujoco", "numpy", "scipy", "python-can", "cantools", "mcap"):
        try:
            found[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            found[package] = "unknown"
    return found


class Traffic:
    """What the runner hears during a run, with the bookkeeping behind loss and lateness.

    Frames are taken as they arrive and logged tick by tick (``flush``). Heartbeats are decoded on
    arrival, since the runner waits for them; everything else is decoded when logged. The runner's
    own frames come back on udp_multicast (loopback): they are recognized by id, counted, and not
    logged twice. A node's heartbeat closing tick j says how many frames it sent for j; frames of
    it missing at that point are counted as lost, and the nodes report in their heartbeats how many
    of the runner's frames they found missing.
    """

    def __init__(self, codec: Codec, recorder: RunRecorder, controller_node: bool = False) -> None:
        self.codec = codec
        self.recorder = recorder
        self.pending: list[tuple[can.Message, Decoded | None]] = []  # arrival order
        self.closed: dict[str, int] = {}  # node -> last tick whose heartbeat arrived
        self.joined: set[str] = set()
        self.left: set[str] = set()
        self.lost: Counter[str] = Counter()  # node -> frames of it the runner did not get
        self.missed_by: dict[str, int] = {}  # node -> runner frames it reported missing
        self.received: Counter[str] = Counter()
        self.echoes = 0
        self._counts: Counter[tuple[str, int]] = Counter()
        own = (RUNNER, PLANT) if controller_node else OWN_SENDERS
        self._own = {spec.frame_id for spec in codec.specs.values() if spec.sender in own}
        self._heartbeats = {spec.frame_id for spec in codec.messages(role=HEARTBEAT)}
        self._commands = {spec.frame_id for spec in codec.messages(role=COMMAND)} if controller_node else set()
        self.commands: dict[int, dict[str, float]] = {}  # tick counter -> the controller node's commands

    def take(self, frame: can.Message) -> None:
        identifier = None if frame.is_extended_id else frame.arbitration_id
        if identifier in self._own:
            self.echoes += 1
            return
        decoded = None
        if identifier in self._heartbeats:
            decoded = self._decode(frame)
            if decoded is not None:
                sender, state = decoded.spec.sender, decoded.values["state"]
                if state == BOOTUP:
                    self.joined.add(sender)
                elif state == STOPPED:
                    self.left.add(sender)
                elif state == OPERATIONAL:
                    self.closed[sender] = decoded.tick
        elif identifier in self._commands:
            decoded = self._decode(frame)
            if decoded is not None:
                channel = decoded.spec.channels[0]
                self.commands.setdefault(decoded.tick, {})[channel.name] = decoded.values[decoded.spec.signals[0]]
        self.pending.append((frame, decoded))

    def _decode(self, frame: can.Message) -> Decoded | None:
        try:
            return self.codec.decode(frame)
        except CodecError:
            return None  # logged raw, as an unknown frame

    def flush(self, tick: int, t: float, t_ns: int) -> None:
        """Account for the frames received during tick k, then log them by arbitration id."""
        taken = []
        for frame, decoded in self.pending:
            if decoded is None:
                decoded = self._decode(frame)
            taken.append((frame, decoded))
            if decoded is None:
                continue
            sender, role = decoded.spec.sender, decoded.spec.role
            self.received[sender] += 1
            if role in (ESTIMATE, CLIENT, COMMAND, CONTROL):
                self._counts[(sender, decoded.tick)] += 1
            elif role == HEARTBEAT and decoded.values["state"] == OPERATIONAL:
                counter = decoded.tick % self.codec.tick_modulus
                self.lost[sender] += max(0, int(decoded.values["frames"]) - self._counts.pop((sender, counter), 0))
                self.missed_by[sender] = int(decoded.values["lost"])
        self.pending.clear()
        for frame, decoded in sorted(taken, key=lambda item: item[0].arbitration_id):
            self.recorder.frame(tick, t, t_ns, frame, decoded)

    @property
    def frames_lost(self) -> int:
        return sum(self.lost.values()) + sum(self.missed_by.values())


class Run:
    """One co-simulation run of a loaded scenario into an MCAP file.

    ``overrides`` (``seed``, ``interface``, ``channel``, ``port``, ``mode``, ``speed``) replace the
    scenario's values, validated like the file's.
    """

    def __init__(self, loaded: LoadedScenario, out: str | Path, seed: int | None = None, **overrides) -> None:
        try:
            scenario = loaded.scenario.with_overrides(seed=seed, **overrides)
        except ScenarioError as error:
            raise ScenarioError(f"{loaded.source}: {error}") from None
        self.loaded, self.scenario, self.out = loaded, scenario, Path(out)
        s = scenario
        try:
            if s.plant.state_space is not None:
                self.plant = StateSpacePlant(s.plant.state_space, s.plant_info, s.sample_time, s.sensors)
            else:
                self.plant = Plant(s.plant_info, s.sample_time, s.sensors)
        except ModelError as error:
            raise ScenarioError(f"{loaded.source}: {error}") from None
        # Estimators are designed on the linearization at the plant's keyframe (its operating point),
        # or at its design keyframe if it has one.
        if s.plant_info.design_keyframe:
            self.plant.reset(keyframe=s.plant_info.design_keyframe)
        self.model = self.plant.linearize()
        needs_continuous = any(estimators.ESTIMATORS[e.kind].continuous for e in s.estimators) or (
            s.controller is not None and controllers.CONTROLLERS[s.controller.kind].continuous)
        try:  # computed even when no estimator needs it: the log records it, for replay to design new ones on
            self.continuous_model = self.plant.linearize(continuous=True)
        except ModelError:  # a discrete-time state-space plant has none
            if needs_continuous:
                raise
            self.continuous_model = None
        self.plant.reset(s.plant.initial_state)
        self.estimators = build_estimators(s, self.model, loaded.source, self.continuous_model)
        self.controller = build_controller(s, self.model, loaded.source, self.continuous_model)
        self.warnings = design_warnings(s, self.estimators)
        self.faults = build_faults(s)
        onset = self.faults.first_onset
        self.onset_tick = None if onset is None else first_tick_at(s, onset)
        self.inputs = [
            next((build_waveform(i.signal) for i in s.inputs if i.actuator == name), fm.Constant(0.0))
            for name in s.actuators
        ]
        self.disturbances = [
            next((build_waveform(d.signal) for d in s.disturbances if d.input == name), fm.Constant(0.0))
            for name in s.disturbance_inputs
        ]
        self.environments = [
            s.plant_info.disturbance_models[d.model](
                np.random.default_rng(np.random.SeedSequence(s.seed, spawn_key=(_ENVIRONMENT, i))), **d.params)
            for i, d in enumerate(s.disturbances) if d.model
        ]
        sensors, actuators, states = s.channels()
        self.codec = s.codec()
        self.units = {
            "states": {c.name: c.unit for c in states},
            "sensors": {c.name: c.unit for c in sensors},
            "actuators": {c.name: c.unit for c in actuators},
            "disturbances": {c.name: c.unit for c in s.plant_info.disturbances},
        }
        self.run_id = uuid4().hex[:12]
        self.bus: BusConfig | None = None
        self.participants: list[Participant] = []

    def node_spec(self, name: str, bus: BusConfig) -> NodeSpec:
        s = self.scenario
        if name == CONTROLLER and s.controller is not None:
            diagnosis = s.controller.diagnosis
            return NodeSpec(CONTROLLER, s.controller.kind, s.controller.params, self.controller.model, self.codec.dbc, bus,
                            s.sample_time, {diagnosis: 1} if diagnosis else {}, diagnosis)
        spec = next(e for e in s.estimators if e.name == name)
        estimator = self.estimators[name]
        return NodeSpec(name, spec.kind, {**spec.params, **estimator.design_params()}, estimator.model, self.codec.dbc, bus,
                        s.sample_time, {CONTROLLER: 0} if s.controller is not None else {})

    def _metadata(self, log: McapLog) -> None:
        s = self.scenario
        est = {
            name: {"kind": e.kind, "messages": [m.name for m in self.codec.data_messages(name)], "states": list(self.model.states),
                   "params": {**next(spec.params for spec in s.estimators if spec.name == name), **e.design_params()},
                   "model": model_to_dict(e.model)}
            for name, e in self.estimators.items()
        }
        log.metadata("cosim.run", {
            "scenario": s.name, "source": self.loaded.source, "seed": str(s.seed), "sample_time": repr(s.sample_time),
            "duration": repr(s.duration), "ticks": str(s.ticks), "plant": s.plant.model,
            "states": json.dumps(list(self.plant.state_names)), "sensors": json.dumps(list(s.sensors)),
            "actuators": json.dumps(list(s.actuators)), "disturbances": json.dumps(list(s.disturbance_inputs)),
            "estimators": json.dumps(est),
            "model": json.dumps(model_to_dict(self.model)),
            "continuous_model": json.dumps(None if self.continuous_model is None else model_to_dict(self.continuous_model)),
            "clients": json.dumps({c.name: {"lockstep": c.lockstep, "messages": [m.name for m in self.codec.data_messages(c.name)]} for c in s.clients}),
            "controller": json.dumps(None if s.controller is None else {
                "kind": s.controller.kind, "params": s.controller.params, "diagnosis": s.controller.diagnosis,
                "messages": [m.name for m in self.codec.data_messages(CONTROLLER)], "model": model_to_dict(self.controller.model)}),
            "fault_onset": json.dumps(self.faults.first_onset),
            "fault_onset_tick": json.dumps(self.onset_tick),
            "faults": json.dumps([{"label": f.label, "kind": f.kind, "start": f.start, "end": f.end if np.isfinite(f.end) else None} for f in self.faults.faults]),
            "bus": json.dumps({"interface": s.bus.interface, "fd": s.bus.fd, "bitrate": s.bus.bitrate, "data_bitrate": s.bus.data_bitrate}),
            "timing": json.dumps(s.timing.model_dump()),
        })
        log.metadata("cosim.scenario", {"source": self.loaded.source, "toml": self.loaded.text, "resolved": s.model_dump_json()})
        log.metadata("cosim.versions", versions())
        if self.plant.info.model_file:
            log.attach(self.plant.info.model_file, "application/xml", self.plant.info.model_path.read_bytes())
        log.attach("cosim.dbc", "text/plain", self.codec.dbc.encode())

    # -- participants -------------------------------------------------------------------------

    def _external(self) -> list[str]:
        """The nodes started by hand ('cosim node NAME --run ID')."""
        names = [e.name for e in self.scenario.estimators if e.external]
        return names + [CONTROLLER] if self.scenario.controller is not None and self.scenario.controller.external else names

    def _start(self, bus: BusConfig, workdir: Path) -> None:
        external = {e.name for e in self.scenario.estimators if e.external}
        for name, estimator in self.estimators.items():
            spec = self.node_spec(name, bus)
            if name in external:
                node = ExternalClient(name, True, kind="node")
            elif bus.interface == "virtual":
                node = LocalNode(spec, estimator)
            else:
                node = ProcessNode(spec, workdir)
            self.participants.append(node)
        if (c := self.scenario.controller) is not None:
            spec = self.node_spec(CONTROLLER, bus)
            if c.external:
                self.participants.append(ExternalClient(CONTROLLER, True, kind="controller"))
            elif bus.interface == "virtual":
                self.participants.append(LocalController(spec, self.controller))
            else:
                self.participants.append(ProcessNode(spec, workdir, kind="controller"))
        self.participants += [ExternalClient(c.name, c.lockstep) for c in self.scenario.clients]

    def _wait(self, bus: can.BusABC, traffic: Traffic, interrupts: DeferredInterrupts, done: Callable[[], bool],
              deadline: float, on_timeout: Callable[[], None]) -> None:
        """Receive into ``traffic`` until ``done()`` or the wall-clock ``deadline``."""
        last_check = time.perf_counter()
        while not done():
            interrupts.check()
            for participant in self.participants:
                participant.service()
            now = time.perf_counter()
            if now >= deadline:
                on_timeout()
                return
            frame = bus.recv(min(_POLL, deadline - now))
            while frame is not None:
                traffic.take(frame)
                frame = bus.recv(0.0)
            if time.perf_counter() - last_check > 0.25:
                last_check = time.perf_counter()
                for participant in self.participants:
                    if (reason := participant.failure()) is not None:
                        raise NodeFailure(reason)
        frame = bus.recv(0.0)
        while frame is not None:  # what else has arrived (a monitor's frames, late echoes)
            traffic.take(frame)
            frame = bus.recv(0.0)

    def _commands(self, bus: can.BusABC, traffic: Traffic, interrupts: DeferredInterrupts, k: int, deadline: float | None,
                  held: np.ndarray) -> np.ndarray:
        """The controller node's commands of tick k: waited for (lockstep), or until the tick's
        deadline (realtime), where a late or missing command holds the actuator's last one."""
        if deadline is None:
            self._wait(bus, traffic, interrupts, lambda: traffic.closed.get(CONTROLLER, -1) >= k,
                       time.perf_counter() + self.scenario.timing.node_timeout, lambda: self._hung(traffic, k, CONTROLLER))
        else:
            self._wait(bus, traffic, interrupts, lambda: traffic.closed.get(CONTROLLER, -1) >= k, deadline, lambda: None)
        got = traffic.commands.pop(k % self.codec.tick_modulus, {})
        for old in [tick for tick in traffic.commands if (k - tick) % self.codec.tick_modulus < self.codec.tick_modulus // 2]:
            del traffic.commands[old]
        return np.array([got.get(name, u) for name, u in zip(self.scenario.actuators, held)])

    def _hung(self, traffic: Traffic, tick: int, name: str | None = None) -> None:
        waiting = [p for p in self.participants if p.lockstep and traffic.closed.get(p.name, -1) < tick and name in (None, p.name)]
        if self.scenario.controller is not None and any(p.name == CONTROLLER for p in waiting):
            waiting = [p for p in waiting if p.name == CONTROLLER]  # the others wait for its commands
        raise NodeFailure(waiting[0].hung(tick, self.scenario.timing.node_timeout))

    def _join(self, bus: can.BusABC, traffic: Traffic, interrupts: DeferredInterrupts) -> None:
        expected = {p.name for p in self.participants}
        timeout = self.scenario.timing.join_timeout

        def late() -> None:
            for participant in self.participants:
                if (reason := participant.failure()) is not None:
                    raise NodeFailure(reason)
            missing = ", ".join(f"{p.kind} {p.name}" for p in self.participants if p.name not in traffic.joined)
            raise NodeFailure(f"{missing} did not join the bus {self.bus.describe()} within {timeout:g} s "
                              f"(raise [timing] join_timeout if it starts slowly)")

        self._wait(bus, traffic, interrupts, lambda: expected <= traffic.joined, time.perf_counter() + timeout, late)

    # -- the run ------------------------------------------------------------------------------

    def _finish(self, bus: can.BusABC, traffic: Traffic, recorder: RunRecorder, log: McapLog, marker: tuple[int, float, int],
                k: int, status: str, error: str, misses: int, warnings: list[str], start: float, startup: float,
                loop: float) -> RunResult:
        """End a run at tick k, however it ends: log what has arrived, stop the nodes (NMT stop), log
        what they sent until then and how the run ended."""
        s, codec = self.scenario, self.codec
        frame = bus.recv(0.0)
        while frame is not None:  # what is already here came before the stop command
            traffic.take(frame)
            frame = bus.recv(0.0)
        traffic.flush(*marker)
        t_end, t_end_ns = s.time(k), k * s.dt_ns
        stop = codec.nmt(NMT_STOP)
        try:
            bus.send(stop)
        except can.CanError:
            pass
        recorder.frame(k, t_end, t_end_ns, stop, codec.decode(stop))
        for participant in self.participants:
            if (warning := participant.stop(timeout=5.0)) is not None and status == "completed":
                warnings.append(warning)
        frame = bus.recv(0.1)
        while frame is not None:
            traffic.take(frame)
            frame = bus.recv(0.02)
        traffic.flush(k, t_end, t_end_ns)
        for warning in warnings:
            recorder.event(k, t_end, t_end_ns, "warning", warning, "warning")
        senders = {
            name: {"frames": traffic.received[name], "lost": traffic.lost[name], "runner_frames_missed": traffic.missed_by.get(name, 0)}
            for name in [*self.estimators, *(c.name for c in s.clients), *([CONTROLLER] if s.controller else [])]
        }
        recorder.event(k, t_end, t_end_ns, "stop", status if not error else f"{status}: {error}", "info" if status == "completed" else "error")
        log.metadata("cosim.result", {
            "status": status, "ticks": str(k), "frames_total": str(recorder.frames),
            "frames_lost": str(traffic.frames_lost), "deadline_misses": str(misses), "error": error,
            "senders": json.dumps(senders),
        })
        return RunResult(self.out, status, k, recorder.frames, traffic.frames_lost, time.perf_counter() - start, s.time(k), error,
                         misses, senders, startup, loop)

    def execute(
        self, on_progress: Callable[[Progress], None] | None = None, progress_every: float = 0.2,
        on_start: Callable[[Run], None] | None = None,
    ) -> RunResult:
        """Run every tick; the log is complete and valid whatever ends the run."""
        s, plant, codec = self.scenario, self.plant, self.codec
        sensor_specs = [codec.specs[f"SENSOR_{n}"] for n in s.sensors]
        command_specs = [codec.specs[f"COMMAND_{n}"] for n in s.actuators]
        dt_ns = s.dt_ns
        realtime = s.timing.mode == "realtime"
        period = s.sample_time / s.timing.speed
        status, error, k, misses = "completed", "", 0, 0
        u_cmd = self.model.u_op.copy()  # what the actuators hold before a controller's first command
        marker = (0, 0.0, 0)  # the tick whose received frames are still to be logged
        startup, tick_start = 0.0, None
        warnings: list[str] = []
        start = time.perf_counter()
        last_report = start
        self.bus = allocate(s.bus.interface, s.bus.channel, s.bus.port, s.bus.fd)
        registration = Registration(self.run_id, {
            "scenario": s.name, "source": self.loaded.source, "seed": s.seed, "sample_time": s.sample_time,
            "bus": self.bus.to_dict(), "dbc": codec.dbc, "log": str(self.out.resolve()),
            "nodes": {name: self.node_spec(name, self.bus).to_json() for name in self._external()},
        })
        with (DeferredInterrupts() as interrupts, McapLog(self.out) as log, open_bus(self.bus) as bus,
              tempfile.TemporaryDirectory(prefix="cosim-nodes-") as workdir, registration):
            recorder = RunRecorder(log, codec, states=plant.state_names, sensors=s.sensors, actuators=s.actuators, units=self.units,
                                   disturbances=s.disturbance_inputs)
            closed_loop = s.controller is not None
            traffic = Traffic(codec, recorder, controller_node=closed_loop)
            self._metadata(log)
            log.metadata("cosim.bus", {key: str(value) for key, value in self.bus.to_dict().items()})
            recorder.event(0, 0.0, 0, "start", f"{s.name} seed={s.seed} ticks={s.ticks} mode={s.timing.mode}")
            for warning in self.warnings:
                recorder.event(0, 0.0, 0, "warning", warning, "warning")
            try:
                self._start(self.bus, Path(workdir))
                if on_start is not None:
                    on_start(self)
                self._join(bus, traffic, interrupts)
                traffic.flush(*marker)  # the boot-up heartbeats
                lockstep = [p.name for p in self.participants if p.lockstep]
                tick_start = time.perf_counter()
                startup = tick_start - start
                for k in range(s.ticks):
                    interrupts.check()
                    t, t_ns = s.time(k), k * dt_ns
                    if realtime:
                        self._wait(bus, traffic, interrupts, lambda: False, tick_start + k * period, lambda: None)
                    x, y_true = plant.state(), plant.sensors()
                    outcome = self.faults.sensors(y_true, t)
                    sent = [
                        codec.encode_decoded(spec.name, k, (value,))
                        for spec, value, on in zip(sensor_specs, outcome.measured, outcome.sent) if on
                    ]
                    commands = [] if closed_loop else [
                        codec.encode_decoded(spec.name, k, (w(t),)) for spec, w in zip(command_specs, self.inputs)]
                    sync = codec.sync(k, len(sent) + len(commands))
                    sent = [(sync, codec.decode(sync)), *sent, *commands]
                    for frame, _ in sent:
                        bus.send(frame)
                    # While the nodes work on tick k: log what the previous tick brought, this
                    # tick's own frames and truth, and advance the physics.
                    traffic.flush(*marker)
                    marker = (k, t, t_ns)
                    for frame, decoded in sent:
                        recorder.frame(k, t, t_ns, frame, decoded)
                    # The actuators receive what the command frames carry (quantized in classic CAN).
                    if closed_loop:
                        u_cmd = self._commands(bus, traffic, interrupts, k, tick_start + (k + 1) * period if realtime else None, u_cmd)
                        if realtime and traffic.closed.get(CONTROLLER, -1) < k:
                            misses += 1
                            recorder.deadline_miss(k, t, t_ns, CONTROLLER, misses)
                    else:
                        u_cmd = np.array([decoded.values[spec.signals[0]] for (_, decoded), spec in zip(commands, command_specs)])
                    u_eff, delta = self.faults.actuators(u_cmd, t)
                    d = np.array([w(t) for w in self.disturbances]) + sum((b(t) for b in self.environments), np.zeros(len(self.disturbances)))
                    recorder.truth(
                        k, t, t_ns, x=x, y_true=y_true, noise=outcome.noise, fault=outcome.fault,
                        measured=np.where(outcome.sent, outcome.measured, np.nan), active=outcome.active, u_cmd=u_cmd,
                        u_eff=u_eff, delta=delta, disturbance=d,
                    )
                    if not np.all(np.isfinite(u_eff)):
                        bad = s.actuators[int(np.flatnonzero(~np.isfinite(u_eff))[0])]
                        raise CosimError(f"actuator {bad}: the effective input at tick {k} is not finite; check its input signal and actuator faults")
                    plant.step(u_eff, d)
                    if realtime:
                        self._wait(bus, traffic, interrupts, lambda: False, tick_start + (k + 1) * period, lambda: None)
                        for name in lockstep:
                            if traffic.closed.get(name, -1) < k and name != CONTROLLER:
                                misses += 1
                                recorder.deadline_miss(k, t, t_ns, name, misses)
                    else:
                        self._wait(bus, traffic, interrupts, lambda k=k: all(traffic.closed.get(n, -1) >= k for n in lockstep),
                                   time.perf_counter() + s.timing.node_timeout, lambda k=k: self._hung(traffic, k))
                    left = traffic.left & set(lockstep)
                    if left:
                        raise NodeFailure(f"{', '.join(sorted(left))} left the bus at tick {k} (stopped heartbeat)")
                    if on_progress is not None and (now := time.perf_counter()) - last_report >= progress_every:
                        last_report = now
                        on_progress(Progress(k + 1, s.ticks, s.time(k + 1), now - start, recorder.frames, misses))
                k = s.ticks
            except BaseException as exc:
                status, error = ending(exc)
                raise
            finally:
                loop = time.perf_counter() - tick_start if tick_start is not None else 0.0
                self.result = self._finish(bus, traffic, recorder, log, marker, k, status, error, misses, warnings, start,
                                           startup, loop)
        if on_progress is not None:
            on_progress(Progress(k, s.ticks, s.time(k), time.perf_counter() - start, self.result.frames, misses))
        return self.result


def run(loaded: LoadedScenario, out: str | Path, seed: int | None = None, on_progress: Callable[[Progress], None] | None = None,
        **overrides) -> RunResult:
    """Run a loaded scenario and write its log to ``out``."""
    return Run(loaded, out, seed, **overrides).execute(on_progress)
