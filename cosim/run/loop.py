"""The tick loop, written once, over a source of ticks: the simulated plant, or a log.

Tick k at t_k = k τ, in four phases:

  1. ``session.begin(k)``: Ctrl-C is taken between ticks; in realtime, wait for the tick's time;
  2. ``session.send(k, source.frames(k))``: the runner's frames of tick k (SYNC(k), then the sensor
     and command frames) go on the bus; while the nodes work on them, the previous tick's traffic
     and these frames are logged (the frames themselves were made while the nodes answered tick
     k − 1: ``run_ticks``);
  3. ``source.advance(k, session)``: the source does what follows the frames: the plant applies
     the commands (in a closed loop, the controller node's, waited for) through the actuator
     faults, logs the truth of tick k and advances the physics; a log copies its truth;
  4. ``session.end(k)``: every lockstep participant has answered tick k (lockstep) or its deadline
     has passed (realtime).

``execute`` wraps the loop: every participant joins first, and whatever ends the run, the nodes
are stopped and the log says how it ended.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from typing import Protocol

import can
import numpy as np

import faults as fm
from cosim import progress
from cosim.bus.codec import CONTROLLER, Codec, Decoded, MessageSpec
from cosim.bus.transport import BusConfig
from cosim.errors import CosimError
from cosim.plant import build_plant
from cosim.plant.fmu_calls import Said
from cosim.run.launcher import ExternalClient, LocalController, LocalNode, ProcessNode
from cosim.run.node import NodeSpec
from cosim.run.outcome import Progress, RunResult, ending
from cosim.run.plan import RunPlan
from cosim.run.session import Session
from cosim.scenario import Scenario, build_faults, build_waveform

_ENVIRONMENT = 0xE1  # spawn key of the disturbance models' random streams (the faults use others)


class Execution:
    """A plan carried out by a session on a bus: what a run and a replay share. ``bus`` and
    ``session`` exist once ``execute`` has started it; ``result`` once it has ended."""

    plan: RunPlan
    bus: BusConfig | None = None
    session: Session | None = None

    @property
    def scenario(self) -> Scenario:
        return self.plan.scenario

    @property
    def result(self) -> RunResult | None:
        """How it ended (once it has)."""
        return self.session.result if self.session is not None else None


class TickSource(Protocol):
    """Where a run's ticks come from."""

    ticks: int

    def frames(self, k: int) -> list[tuple[can.Message, Decoded | None]]:
        """The runner's frames of tick k, SYNC(k) first, each with what a receiver decodes from it
        (None for a frame the run's database does not describe). Called right after
        ``advance(k − 1)``, before tick k − 1 is closed: it may depend on the source's own state
        after that, not on the session's."""

    def advance(self, k: int, session: Session) -> None:
        """What follows tick k's frames on the bus, before the tick is closed.

        A source may also have ``finish(k, session)``: called as the run ends after k ticks (however
        it ends), before the session logs how (an FMU plant's last messages, as it is freed)."""


class PlantSource:
    """Ticks of the simulated plant: sense, inject the sensor faults, encode; then actuate through the
    actuator faults, log the truth and step the physics.

    The actuators hold the operating point's inputs until a controller node's first command; in an
    open-loop run they receive the scenario's input signals as the command frames carry them
    (quantized in classic CAN). An input the scenario does not drive holds its start value (an
    FMU's start values; 0 for the other plants), a disturbance input likewise.

    ``interrupted``: what an FMU plant in a process of its own calls while it waits for the FMU (the
    session's ``interrupts.check``: Ctrl-C and SIGTERM stop even an FMU that never answers)."""

    def __init__(self, plan: RunPlan, interrupted: Callable[[], None] | None = None) -> None:
        s = self.scenario = plan.scenario
        self.codec = plan.codec
        self.ticks = s.ticks
        self.plant = build_plant(s, interrupted)
        self.plant.reset(s.plant.initial_state)
        self.faults = build_faults(s)
        self.closed_loop = s.controller is not None
        u_start, d_start = held_inputs(plan, self.plant)
        self.inputs = [
            next((build_waveform(i.signal) for i in s.inputs if i.actuator == name), fm.Constant(float(u0)))
            for name, u0 in zip(s.actuators, u_start)
        ]
        self.disturbances = [
            next(
                (build_waveform(d.signal) for d in s.disturbances if d.input == name and d.signal is not None),
                fm.Constant(float(d0)),
            )
            for name, d0 in zip(s.disturbance_inputs, d_start)
        ]
        self.environments = [
            s.plant_info.disturbance_models[d.model](
                np.random.default_rng(np.random.SeedSequence(s.seed, spawn_key=(_ENVIRONMENT, i))), **d.params
            )
            for i, d in enumerate(s.disturbances)
            if d.model
        ]
        self.sensor_specs = [plan.codec.sensor(n) for n in s.sensors]
        self.command_specs = [plan.codec.command(n) for n in s.actuators]
        self.u_cmd = u_start.copy()  # what the actuators hold before a controller's first command
        self._sensed: tuple[np.ndarray, np.ndarray, fm.SensorOutcome] | None = None
        self._commands: list[tuple[can.Message, Decoded]] = []
        self.said = Said()
        """What the plant (an FMU) logged or printed, counted (the run's log has each message)."""

    def frames(self, k: int) -> list[tuple[can.Message, Decoded | None]]:
        codec, t = self.codec, self.scenario.time(k)
        x, y_true = self.plant.state(), self.plant.sensors()
        outcome = self.faults.sensors(y_true, t)
        self._sensed = (x, y_true, outcome)
        commands = [] if self.closed_loop else [w(t) for w in self.inputs]
        frames = runner_frames(
            codec, k, self.sensor_specs, outcome.measured, outcome.sent, self.command_specs, commands
        )
        self._commands = [(m, d) for m, d in frames[len(frames) - len(commands) :] if d is not None]
        return frames

    def advance(self, k: int, session: Session) -> None:
        s, t = self.scenario, self.scenario.time(k)
        assert self._sensed is not None
        x, y_true, outcome = self._sensed
        if self.closed_loop:
            self.u_cmd = session.commands(k, s.actuators, self.u_cmd)
        else:
            self.u_cmd = np.array(
                [decoded.values[spec.signals[0]] for (_, decoded), spec in zip(self._commands, self.command_specs)]
            )
        u_eff, delta, d = self.actuate(self.u_cmd, t)
        session.recorder.truth(
            k,
            t,
            k * s.dt_ns,
            x=x,
            y_true=y_true,
            noise=outcome.noise,
            fault=outcome.fault,
            measured=np.where(outcome.sent, outcome.measured, np.nan),
            active=outcome.active if session.bus_faults is None else (*outcome.active, *session.bus_faults.active(t)),
            u_cmd=self.u_cmd,
            u_eff=u_eff,
            delta=delta,
            disturbance=d,
        )
        self.step(k, u_eff, d)
        self._log_plant_messages(k, session)

    def actuate(self, u_cmd: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The commands through the actuator faults at time t: the effective inputs, the
        effectiveness factors and the disturbance inputs (signals and disturbance models)."""
        u_eff, delta = self.faults.actuators(u_cmd, t)
        return u_eff, delta, self.disturbance(t)

    def disturbance(self, t: float) -> np.ndarray:
        """The disturbance inputs at time t: their signals plus the disturbance models' outputs."""
        return np.array([w(t) for w in self.disturbances]) + sum(
            (b(t) for b in self.environments), np.zeros(len(self.disturbances))
        )

    @staticmethod
    def disturbances_of(sources: Sequence[PlantSource]) -> Callable[[np.ndarray, float], np.ndarray]:
        """``disturbance`` of K runs at once (a batch's): (rows, t) → (len(rows), inputs), each row bit
        for bit its run's. The environment models at each place, where all the runs' are of one kind
        whose class offers ``batched(models)`` (b(t) of them all, (K, inputs)), are evaluated together."""
        width = len(sources[0].disturbances)
        if width == 0:  # a plant without disturbance inputs (the masses, the tanks): nothing per tick
            return lambda rows, t: np.zeros((len(rows), 0))
        if len({len(source.environments) for source in sources}) != 1:  # runs of other environments
            return lambda rows, t: np.array([sources[r].disturbance(t) for r in rows.tolist()]).reshape(
                len(rows), width
            )
        environments = [_together(list(models)) for models in zip(*(source.environments for source in sources))]

        def disturbance(rows: np.ndarray, t: float) -> np.ndarray:
            signals = np.array([[w(t) for w in sources[r].disturbances] for r in rows.tolist()]).reshape(
                len(rows), width
            )
            total = np.zeros((len(sources), width))
            for b in environments:  # as ``sum`` adds them, from 0
                total = total + b(t)
            return signals + total[rows]

        return disturbance

    def step(self, k: int, u_eff: np.ndarray, d: np.ndarray) -> None:
        """Advance the physics over tick k with these inputs (a non-finite one is the run's error)."""
        self.check_inputs(k, u_eff)
        self.plant.step(u_eff, d)

    def check_inputs(self, k: int, u_eff: np.ndarray) -> None:
        """CosimError naming the first actuator whose effective input at tick k is not finite."""
        if not np.all(np.isfinite(u_eff)):
            bad = self.scenario.actuators[int(np.flatnonzero(~np.isfinite(u_eff))[0])]
            raise CosimError(
                f"actuator {bad}: the effective input at tick {k} is not finite; check its input signal and actuator "
                "faults"
            )

    def _log_plant_messages(self, k: int, session: Session) -> None:
        take = getattr(self.plant, "take_messages", None)
        if take is not None and (messages := take()):
            self.said.add(messages)
            session.recorder.fmu_messages(k, *session.time(k), messages)

    def finish(self, k: int, session: Session) -> None:
        self.close()
        self._log_plant_messages(k, session)

    def close(self) -> None:
        """Free the plant (an FMU's instance)."""
        close = getattr(self.plant, "close", None)
        if close is not None:
            close()


def _together(models: list[Callable[[float], np.ndarray]]) -> Callable[[float], np.ndarray]:
    """b(t) of K runs' environment models (K, inputs): their class's ``batched`` form where they are
    all of one class that has one (and it takes them), else each model by itself."""
    kind = type(models[0])
    batched = getattr(kind, "batched", None)
    if batched is not None and all(type(model) is kind for model in models):
        found = batched(models)
        if found is not None:
            return found
    return lambda t: np.stack([model(t) for model in models])


def runner_frames(
    codec: Codec,
    k: int,
    sensor_specs: Sequence[MessageSpec],
    measured: Iterable[float],
    sent: Iterable[bool],
    command_specs: Sequence[MessageSpec],
    commands: Iterable[float],
) -> list[tuple[can.Message, Decoded | None]]:
    """The runner's frames of tick k: SYNC(k) announcing them, the sensor frames of the readings
    ``sent`` (``measured``), the command frames of ``commands`` (an open loop's input signals;
    none in a closed loop), each with what a receiver decodes from it. A batch
    (``cosim.campaign.batch_bus``) builds a run's frames with it where its bus faults need them."""
    data = [codec.encode_decoded(spec.name, k, (value,)) for spec, value, on in zip(sensor_specs, measured, sent) if on]
    data += [codec.encode_decoded(spec.name, k, (u,)) for spec, u in zip(command_specs, commands)]
    sync = codec.sync(k, len(data))
    return [(sync, codec.decode(sync)), *data]


def held_inputs(plan: RunPlan, plant: object) -> tuple[np.ndarray, np.ndarray]:
    """What the actuators and the disturbance inputs hold while nothing drives them: an FMU's start
    values, else the operating point's inputs (and no disturbance)."""
    s = plan.scenario
    start = getattr(plant, "start_inputs", None)
    if start is not None:
        m = len(s.actuators)
        return np.asarray(start[:m], dtype=float), np.asarray(start[m:], dtype=float)
    assert plan.model is not None  # only an FMU plant may have none
    return plan.model.u_op.copy(), np.zeros(len(s.disturbance_inputs))


def run_ticks(source: TickSource, session: Session, advanced: Callable[[int], None]) -> int:
    """Every tick of ``source`` through ``session``; returns the number of ticks run.

    The frames of tick k + 1 are made while the nodes answer tick k (between ``advance(k)`` and
    ``end(k)``): with node processes, sensing, faults and encoding leave the lockstep's critical
    path (in-process nodes answer in this thread, within ``end``: there it changes nothing). What
    making them raises is raised where it was before, when tick k + 1 sends them."""
    upcoming = _Upcoming(source, 0)
    for k in range(source.ticks):
        session.begin(k)
        session.send(k, upcoming.frames())
        source.advance(k, session)
        if k + 1 < source.ticks:
            upcoming = _Upcoming(source, k + 1)
        session.end(k)
        advanced(k + 1)
    return source.ticks


class _Upcoming:
    """A tick's frames, made ahead of their tick; an error making them waits for it."""

    __slots__ = ("_frames", "_error")

    def __init__(self, source: TickSource, k: int) -> None:
        self._frames: list[tuple[can.Message, Decoded | None]] = []
        self._error: Exception | None = None
        try:
            self._frames = source.frames(k)
        except Exception as error:  # noqa: BLE001 (re-raised by frames(), at its tick)
            self._error = error

    def frames(self) -> list[tuple[can.Message, Decoded | None]]:
        if self._error is not None:
            raise self._error
        return self._frames


def execute(
    source: TickSource,
    session: Session,
    start: Callable[[], None],
    senders: list[str],
    on_progress: Callable[[Progress], None] | None = None,
    progress_every: float = 0.2,
) -> RunResult:
    """Start the participants (``start`` adds them to ``session.participants``), wait for them to
    join, run every tick of ``source`` and finish the log, however the run ends: the log then says
    how it ended and what each of ``senders`` sent. Re-raises what stopped it."""
    status, error, k = "completed", "", 0
    last_report = time.perf_counter()

    def advanced(done: int) -> None:
        nonlocal k, last_report
        k = done
        if on_progress is not None and (now := time.perf_counter()) - last_report >= progress_every:
            last_report = now
            on_progress(session.progress(done, source.ticks))

    try:
        with progress.step("starting the nodes"):
            start()
        joining = len(session.participants)
        with progress.step(f"waiting for {joining} participant{'' if joining == 1 else 's'} to join"):
            session.join()
        k = run_ticks(source, session, advanced)
    except BaseException as exc:
        status, error = ending(exc)
        raise
    finally:
        finish = getattr(source, "finish", None)
        if finish is not None:
            with session.interrupts.shielded():
                try:
                    finish(k, session)
                except Exception as exc:  # noqa: BLE001 (freeing the FMU must not keep the log from its end)
                    session.warnings.append(f"the plant did not close cleanly: {exc}")
        result = session.finish(k, status, error, senders)
        if on_progress is not None:
            on_progress(session.progress(k, source.ticks))
    return result


def start_participants(
    plan: RunPlan, session: Session, node_spec: Callable[[str, BusConfig], NodeSpec] | None = None
) -> None:
    """Start the estimator nodes, the controller node and wait for the declared clients of a run,
    each added to the session's participants as soon as it exists (to be stopped, whatever comes)."""
    s, bus = plan.scenario, session.config
    node_spec = node_spec or plan.node_spec
    external = set(plan.external_nodes)
    found = session.participants
    for name, estimator in plan.estimators.items():
        spec = node_spec(name, bus)
        if name in external:
            found.append(ExternalClient(name, True, kind="node"))
        elif bus.interface == "virtual":
            found.append(LocalNode(spec, estimator))
        else:
            found.append(ProcessNode(spec, session.workdir))
    if s.controller is not None and plan.controller is not None:
        spec = node_spec(CONTROLLER, bus)
        if CONTROLLER in external:
            found.append(ExternalClient(CONTROLLER, True, kind="controller"))
        elif bus.interface == "virtual":
            found.append(LocalController(spec, plan.controller))
        else:
            found.append(ProcessNode(spec, session.workdir, kind="controller"))
    found += [ExternalClient(c.name, c.lockstep) for c in s.clients]
