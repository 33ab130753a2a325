"""Batched runs: the runs of one plan that differ only in their seed, stepped together.

A campaign's replicates share a configuration (scenario and settings) and differ in their seed;
the runs of its axes and samples often differ only in what acts on each run's own plant (its faults,
noise, disturbances, inputs, initial state). ``run_batch`` steps K runs of one configuration, and
``run_together`` K runs of any configurations, in lockstep in one process wherever their designs
agree (``_shared``: the estimators and controller as designed, the sensors, actuators, bus and
ticks), every per-tick array with a leading run axis, so that each call pays its overhead once for
K runs: the estimators through their batched
step (``estimators.batched``: one stacked NumPy call for K runs where the kind has one), the CAN
codec's quantization as array arithmetic (``Codec.carried``), the scores fed whole ticks
(``Scorer.tick``). Each run keeps its own plant, inputs, faults and random streams (its seed's, as
alone); the sensor faults of runs configured alike act on arrays (``FaultInjector.sensors_batch``).

What a batch computes is what a run's metrics row reads, bit for bit what the run gives alone
(``cosim run --seed``, or a campaign with ``--batch 1``): the values each estimator receives (the
sensor and command frames' values as the frames carry them), its estimates as its node's frames
carry them (saturated at their signal's range, quantized), and the truth they are scored against.
On the in-process ideal bus without bus faults, a run's frames all arrive in their tick, so this is
the whole of what the bus does to them; where its bus does more (attacks and losses of the
sensors' frames, SecOC, the intrusion detector) ``cosim.campaign.batch_bus`` gives what it does. On
an arbitrated wire, ``cosim.campaign.batch_wire`` drives each run's own wire, bus faults, detector
and nodes' protocol with the frames the run sends alone (each node computes on the tick its own
client took, and publishes what the batch computed for it), and the scores read the estimators'
frames the wire delivered. The frames' counts and the bus load are not computed: a batched run's
``RunMetrics`` holds its row's metrics, with the bus's only the detector's and SecOC's scores and
the frames lost (a run whose log is kept runs alone).

A run that would not end as a completed run of the batch (a value outside its signal's range, an
estimate that is not a number, an estimator that raises, a non-finite input or state) leaves the
batch at that tick and is run again alone, through the whole run (``RunPlan``, ``Session``, nodes):
it then ends exactly as it ends alone, and the others go on. A plan the batch cannot express
(``refusal``: node processes, an FMU plant, a controller without a linear model, clients,
realtime; ``batch_bus.refusal``: on the ideal bus, bus faults a batch does not emulate, SecOC or the
detector in a closed loop, other traffic; ``batch_wire.refusal``: SecOC on an arbitrated wire) runs
every run alone.
"""

from __future__ import annotations

import copy
import dataclasses
import pickle
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

import faults as fm
from cosim.analysis.metrics import BusMetrics, RunMetrics
from cosim.analysis.metrics.compute import TickScoring
from cosim.analysis.metrics.scorer import TickBatch
from cosim.bus.codec import COMMAND, CONTROLLER, ranges
from cosim.campaign.batch_bus import BusBatch, acts
from cosim.campaign.batch_bus import refusal as bus_refusal
from cosim.campaign.batch_estimators import Estimators, Stepped
from cosim.campaign.batch_wire import WireBatch
from cosim.errors import CosimError
from cosim.log.metadata import RESULT, RUN, SCENARIO, ResultRecord, SenderCounts
from cosim.plant.fmu_model import is_fmu
from cosim.plant.physics_batch import physics_of
from cosim.run.loop import PlantSource
from cosim.run.plan import RunPlan
from cosim.scenario import LoadedScenario


@dataclass(frozen=True)
class BatchedRun:
    """One run of a batch: its seed, and either its metrics (it ran in the batch to its end) or why
    it left the batch (``left``: it is to be run alone, which gives its result)."""

    seed: int
    metrics: RunMetrics | None = None
    left: str = ""
    refused: str = ""
    """Why it did not step in a batch at all (``refusal``, or its plan's error): to be run alone."""


UNBUILT = (
    "the frames, which a batched run does not build: no bus figures (frames per id, load); the same run alone "
    "(cosim run --seed) has them"
)
"""What a batched run's metrics say they lack: everything of its row is there."""


def refusal(plan: RunPlan) -> str | None:
    """Why the runs of ``plan`` cannot step in a batch (None: they can)."""
    s = plan.scenario
    reasons = [
        (s.bus.interface != "virtual", "its nodes run in processes of their own (a batch needs the in-process bus)"),
        (is_fmu(s.plant.model), "its plant is an FMU, which runs in a process of its own"),
        (s.controller is not None and plan.controller is None, "its controller has no linear model"),
        (bool(s.clients), "clients share its bus"),
        (bool(plan.external_nodes), "some of its nodes are started by hand"),
        (s.timing.mode != "lockstep", "it runs in realtime"),
        (plan.model is None, "it has no linear model"),
    ]
    return next((why for refuse, why in reasons if refuse), None) or bus_refusal(plan)


class _Run:
    """One run's own parts in a batch: its plan (its seed's scenario), plant and faults, scores."""

    def __init__(self, plan: RunPlan) -> None:
        assert plan.scenario.seed is not None
        self.seed = plan.scenario.seed
        self.plan = plan
        self.source = PlantSource(self.plan)
        self.scoring = TickScoring(
            {
                RUN: self.plan.run_record(start_time_ns=0).to_metadata(),
                SCENARIO: self.plan.scenario_record().to_metadata(),
            },
            self.plan.codec.dbc,
        )
        self.left = ""

    def leave(self, k: int, why: str) -> None:
        if not self.left:
            self.left = f"tick {k}: {why}"

    def metrics(
        self, ticks: int, contested: int = 0, missed: int = 0, senders: dict[str, SenderCounts] | None = None
    ) -> RunMetrics:
        """Its metrics after ``ticks`` ticks: ``contested`` of them (intruders' frames without
        authentication), ``missed`` the runner's frames each node found missing (or ``senders``:
        what each node sent, lost and missed, as its runner's traffic counts it)."""
        if senders is None:
            senders = {name: SenderCounts(runner_frames_missed=missed) for name in self.plan.senders}
        lost = sum(c.lost + c.runner_frames_missed for c in senders.values())
        result = ResultRecord(
            "completed", ticks, None, lost, 0, "", senders, {"datagrams": 0, "frames": 0}, contested_ticks=contested
        )
        found = self.scoring.metrics(RESULT, result.to_metadata())
        # No frames were built: say so rather than report none (the topics' counts come from a log);
        # what the bus's own schemes said (the detector, SecOC) and the frames lost are kept
        missing = [m for m in found.missing if not m.startswith("/")] + [UNBUILT]
        bus = found.bus
        kept = (
            BusMetrics(
                fd=bus.fd,
                lost=bus.lost,
                intrusion_detection=bus.intrusion_detection,
                secoc_detection=bus.secoc_detection,
                secoc_rejected=bus.secoc_rejected,
            )
            if bus is not None and (bus.intrusion_detection is not None or bus.secoc_detection is not None)
            else None
        )
        return replace(found, bus=kept, channels={}, missing=missing)


class _Controller:
    """The controller node over the batch's runs: its K instances, each stepped by itself on its
    run's readings and the diagnosis node's report of the tick before (as its node's upstream lag
    of 1 has it), its commands as their frames carry them."""

    def __init__(self, plans: Sequence[RunPlan], sensors: tuple[str, ...], actuators: tuple[str, ...]) -> None:
        self.instances = [copy.deepcopy(plan.controller) for plan in plans if plan.controller is not None]
        self.batch = type(self.instances[0]).batched(self.instances)  # its own batched step, or None
        model = self.instances[0].model
        s, codec = plans[0].scenario, plans[0].codec
        assert s.controller is not None
        self.diagnosis = s.controller.diagnosis
        self.outputs = [sensors.index(n) if n in sensors else -1 for n in model.outputs]
        messages = codec.data_messages(CONTROLLER)
        commands = [m for m in messages if m.role == COMMAND]
        self.status = [m for m in messages if m.role != COMMAND]
        channels = [c for m in commands for c in m.channels]
        self.command_inputs = [list(model.inputs).index(c.name) for c in channels]  # the node's _inputs
        self.columns = [actuators.index(c.name) for c in channels]
        self.status_signals = [signal for m in self.status for signal in m.signals]
        self.signals = [signal for m in commands for signal in m.signals] + self.status_signals  # as in ``raw``
        self.carried = codec.carried_of(commands)
        self.command_range = ranges(commands)
        self.status_range = ranges(self.status)
        self.commanded = np.zeros(len(actuators), dtype=bool)
        self.commanded[self.columns] = True
        self.t = s.sample_time

    def step(
        self, k: int, readings: np.ndarray, given: list[dict[str, float]], runs: Sequence[_Run], alive: np.ndarray
    ) -> np.ndarray:
        """Tick k's commands by actuator (K, actuators; the others NaN), from each run's readings and
        the diagnosis node's report it has (``given``); a run whose controller raises or asks for
        what its frames cannot carry leaves the batch. ``raw``: its commands and status, by ``signals``."""
        found = np.full((len(runs), len(self.commanded)), np.nan)
        u = np.zeros((len(runs), len(self.columns)))
        status = np.zeros((len(runs), len(self.status_signals)))
        t = k * self.t  # the tick's time as its node has it (the tick counter times the sample time)
        ys = np.stack([readings[:, i] if i >= 0 else np.full(len(runs), np.nan) for i in self.outputs], axis=1)
        ys = np.where(alive[:, None], ys, 0.0)
        if self.batch is not None:
            try:
                commands, diagnostics = self.batch.step(ys, t, given)
                u[:] = commands[:, self.command_inputs]
                for i, signal in enumerate(self.status_signals):
                    status[:, i] = diagnostics[signal]
            except Exception as error:  # noqa: BLE001 (a bug of the controller's: each run ends with it, alone)
                for r in map(int, np.flatnonzero(alive)):
                    runs[r].leave(k, f"the controller raised {type(error).__name__}: {error}")
                alive[:] = False
        for r in map(int, np.flatnonzero(alive)) if self.batch is None else ():
            try:
                command = self.instances[r].step(ys[r], t, given[r])
                u[r] = [float(command.u[i]) for i in self.command_inputs]
                status[r] = [command.diagnostics[signal] for signal in self.status_signals]
            except Exception as error:  # noqa: BLE001 (a bug of the controller's: its run ends with it, alone)
                runs[r].leave(k, f"the controller raised {type(error).__name__}: {error}")
                alive[r] = False
        _leave_outside(k, alive, u, self.command_range, runs, "a command outside its signal's range")
        _leave_outside(k, alive, status, self.status_range, runs, "a controller status outside its signal's range")
        self.raw = np.concatenate([u, status], axis=1)
        found[:, self.columns] = self.carried(np.where(alive[:, None], u, 0.0))
        return found


def run_batch(
    loaded: LoadedScenario, seeds: Sequence[int], on_tick: Callable[[int, int], None] | None = None
) -> list[BatchedRun]:
    """The runs of ``loaded`` with each of ``seeds``, stepped together on the in-process bus.
    Raises CosimError (naming why) for a scenario whose runs cannot step in a batch (``refusal``),
    or whose plan cannot be built; a run that leaves the batch says why in ``left``."""
    plan = RunPlan.build(loaded, seeds[0], interface="virtual")
    why = refusal(plan)
    if why is not None:
        raise CosimError(f"{loaded.source}: not batched: {why}")
    return _Batch([_seeded(plan, seed) for seed in seeds]).run(on_tick)


def run_together(
    members: Sequence[tuple[LoadedScenario, int]], on_tick: Callable[[int, int], None] | None = None
) -> list[BatchedRun]:
    """Runs of any configurations (each a scenario with its settings, and a seed), in order: those
    whose designs agree (``_shared``) step together, one batch after another; a run the batch
    cannot express, or whose plan cannot be built, says why in ``refused`` (alone, it says the same
    or runs). ``on_tick(k, ticks)`` follows each batch in turn."""
    found: dict[int, BatchedRun] = {}
    configured: dict[tuple[str, str], tuple[RunPlan, Any] | str] = {}  # one plan per configuration, then seeded
    groups: dict[Any, list[tuple[int, RunPlan]]] = {}
    for i, (loaded, seed) in enumerate(members):
        key = (loaded.text, repr(loaded.settings))
        if key not in configured:
            built = _plan_or_why(loaded, seed)
            configured[key] = built if isinstance(built, str) else (built, _shared(built))
        known = configured[key]
        if isinstance(known, str):
            found[i] = BatchedRun(seed, refused=known)
        else:
            groups.setdefault(known[1], []).append((i, _seeded(known[0], seed)))
    for group in groups.values():
        rows, plans = zip(*group)
        found.update(zip(rows, _Batch(plans).run(on_tick)))
    return [found[i] for i in range(len(members))]


def _plan_or_why(loaded: LoadedScenario, seed: int) -> RunPlan | str:
    """The plan of ``loaded``, or why its runs step alone (its refusal, or why it cannot be built)."""
    try:
        plan = RunPlan.build(loaded, seed, interface="virtual")
    except CosimError as error:
        return f"its plan cannot be built ({error})"
    return refusal(plan) or plan


def _seeded(plan: RunPlan, seed: int) -> RunPlan:
    return replace(plan, scenario=plan.scenario.with_overrides(seed=seed))


def _shared(plan: RunPlan) -> Any:
    """What the runs of one batch have in common, as one comparable value: everything but each
    run's plant, inputs, disturbances, faults and seed (its ``_Run``). Each estimator counts as its
    node would build it (kind, model, parameters with its design's, sample time: the same whether
    designed or taken from the design cache), the controller as designed (pickled). One that does
    not pickle batches only with runs of its own configuration."""
    s = plan.scenario
    try:
        return pickle.dumps(
            (s.ticks, s.sample_time, s.sensors, s.actuators, s.bus, s.timing, s.controller, plan.state_names)
            + tuple((name, *_as_built(e)) for name, e in plan.estimators.items())
            + (plan.controller,)
        )
    except Exception:  # noqa: BLE001 (a plugin's state may hold anything)
        return (plan.loaded.text, repr(plan.loaded.settings))


def _as_built(estimator: Any) -> tuple[Any, ...]:
    params = {**dataclasses.asdict(estimator.params), **estimator.node_params()}
    return type(estimator).__qualname__, estimator.model, sorted(params.items()), estimator.sample_time


class _Batch:
    def __init__(self, plans: Sequence[RunPlan]) -> None:
        plan = plans[0]
        s = self.scenario = plan.scenario
        self.runs = [_Run(each) for each in plans]
        self.physics = physics_of([run.source.plant for run in self.runs])
        self.codec = plan.codec
        self.sensor_specs = [self.codec.sensor(n) for n in s.sensors]
        self.command_specs = [self.codec.command(n) for n in s.actuators]
        self.actuators = s.actuators  # a property that asks the plant's description each time
        self.sensors_carried = self.codec.carried_of(self.sensor_specs)
        self.commands_carried = self.codec.carried_of(self.command_specs)
        self.sensor_range = ranges(self.sensor_specs)
        self.command_range = ranges(self.command_specs)
        self.estimators = [Estimators(name, plans, s.sensors, s.actuators) for name in plan.estimators]
        self.stepped = Stepped.of(self.estimators)
        self.controller = _Controller(plans, s.sensors, s.actuators) if plan.controller is not None else None
        self.report: tuple[list[str], np.ndarray] | None = None  # the diagnosis node's last values
        self.state_names = plan.state_names
        self.held = np.stack([run.source.u_cmd for run in self.runs])  # what the actuators hold
        self.scores = TickBatch(
            [run.scoring.scorer for run in self.runs], {e.name: e.signals for e in self.estimators}, plan.state_names
        )
        self.raw_commands = np.zeros((len(plans), len(s.actuators)))  # an open loop's, as its input signals give them
        self.wire = (
            WireBatch(plans, self.scores, self.sensor_specs, self.command_specs, self._leave)
            if s.bus.timing == "arbitrated"
            else None
        )
        self.bus = (
            BusBatch(plans, self.sensor_specs, self.command_specs, [e.messages for e in self.estimators], self._leave)
            if acts(plan) and self.wire is None
            else None
        )
        self.disturbance = PlantSource.disturbances_of([run.source for run in self.runs])
        alike: dict[str, list[int]] = {}  # runs whose sensor faults and noise are configured alike
        for r, run in enumerate(self.runs):
            alike.setdefault(repr((run.plan.scenario.noise, run.plan.scenario.faults)), []).append(r)
        self.alike = [np.array(rows) for rows in alike.values()]

    def run(self, on_tick: Callable[[int, int], None] | None) -> list[BatchedRun]:
        s, runs = self.scenario, self.runs
        ticks = s.ticks
        alive = np.ones(len(runs), dtype=bool)
        try:
            for k in range(ticks):
                if not alive.any():
                    break
                self._tick(k, alive)
                if on_tick is not None:
                    on_tick(k + 1, ticks)
            return [
                BatchedRun(run.seed, left=run.left) if run.left else BatchedRun(run.seed, self._metrics(r, ticks))
                for r, run in enumerate(runs)
            ]
        finally:
            if self.wire is not None:
                self.wire.close()

    def _metrics(self, r: int, ticks: int) -> RunMetrics:
        """Run r's metrics after its last tick, with what its bus counted."""
        bus, wire, run = self.bus, self.wire, self.runs[r]
        if wire is not None:
            contested, senders = wire.finish(r, ticks)
            return run.metrics(ticks, contested, senders=senders)
        return run.metrics(ticks, *((int(bus.contested[r]), int(bus.missed[r])) if bus is not None else ()))

    def _leave(self, r: int, k: int, why: str) -> None:
        self.runs[r].leave(k, why)

    def _tick(self, k: int, alive: np.ndarray) -> None:
        """Tick k of the runs still ``alive`` (a run that leaves is taken out of it)."""
        t = self.scenario.time(k)
        x = self.physics.state()
        y_true = self.physics.sensors()  # a run that left: its last, unused
        measured, sent, active = self._sensors(y_true, t)
        middle = 0.5 * (self.sensor_range[0] + self.sensor_range[1])
        self._check(k, alive, np.where(sent, measured, middle), self.sensor_range, "a sensor reading outside its range")
        carried = self.sensors_carried(np.where(sent, measured, 0.0))
        readings = np.where(sent, carried, np.nan)
        self._check(k, alive, x, None, "a state that is not finite")
        if self.wire is not None:
            self._tick_wire(k, t, x, measured, sent, readings, active, alive)
            return
        u_cmd, commanded = self._commands(k, t, readings, alive)
        bus = self.bus
        if bus is not None:  # what the nodes take of the runner's frames, and what the bus's schemes see
            active = [(*a, *b) for a, b in zip(active, bus.active(t))]
            bounds = (self.sensor_range, self.command_range)
            readings = bus.runner(k, measured, sent, carried, self.raw_commands, u_cmd, bounds, alive)
        values = self._estimates(k, [(readings, u_cmd, commanded)] * len(self.estimators), alive)
        if values is None:
            return
        rows = np.flatnonzero(alive)
        verdicts = None
        if bus is not None:
            bus.estimates(k, values, [(e.lower, e.upper) for e in self.estimators])
            verdicts = bus.verdicts()
        self.scores.tick(k, rows, x, active, values, verdicts)
        self._advance(k, t, rows, u_cmd, alive)

    def _sensors(self, y_true: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray, list[tuple[str, ...]]]:
        """Each run's readings through its sensor faults and noise (``FaultInjector.sensors``): the
        measured values, which are sent, and its active faults; runs configured alike on arrays."""
        runs = self.runs
        if len(self.alike) == 1:
            return fm.FaultInjector.sensors_batch([run.source.faults for run in runs], y_true, t)
        measured, sent = np.empty_like(y_true), np.empty(y_true.shape, dtype=bool)
        active: list[tuple[str, ...]] = [()] * len(runs)
        for rows in self.alike:
            injectors = [runs[r].source.faults for r in rows]
            measured[rows], sent[rows], found = fm.FaultInjector.sensors_batch(injectors, y_true[rows], t)
            for r, labels in zip(rows.tolist(), found):
                active[r] = labels
        return measured, sent, active

    def _commands(self, k: int, t: float, readings: np.ndarray, alive: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tick k's commands by actuator (what the actuators hold where none came) and which came:
        the input signals as the runner's frames carry them, or the controller node's."""
        runs = self.runs
        if self.controller is None:
            commands = np.array(
                [
                    [w(t) for w in run.source.inputs] if alive[r] else [0.0] * len(self.actuators)
                    for r, run in enumerate(runs)
                ]
            ).reshape(len(runs), len(self.actuators))
            self._check(k, alive, commands, self.command_range, "an input signal outside its command's range")
            self.raw_commands = commands
            u_cmd, commanded = self.commands_carried(commands), np.ones(len(self.actuators), dtype=bool)
        else:
            report = self.report
            given = [{} for _ in runs] if report is None else [dict(zip(report[0], r)) for r in report[1].tolist()]
            u_cmd, commanded = self.controller.step(k, readings, given, runs, alive), self.controller.commanded
        self.held = np.where(commanded, u_cmd, self.held)
        return self.held, commanded

    def _tick_wire(
        self,
        k: int,
        t: float,
        x: np.ndarray,
        measured: np.ndarray,
        sent: np.ndarray,
        readings: np.ndarray,
        active: list,
        alive: np.ndarray,
    ) -> None:
        """Tick k on the runs' arbitrated buses (``batch_wire``): each node computes on what its own
        tick brought it, and its answers go on its run's wire. ``readings``: the runner's sensor
        values as their frames carry them (NaN: not sent)."""
        wire, controller = self.wire, self.controller
        assert wire is not None
        none = np.full((len(self.runs), len(self.actuators)), np.nan)
        if controller is None:  # the input signals, as given and as their frames carry them
            u_carried, _ = self._commands(k, t, measured, alive)
        wire.send(k, measured, sent, self.raw_commands, alive)
        if controller is not None:
            ticks, taken_readings, _ = wire.inputs(k, CONTROLLER, alive, (readings, none))
            given = [tick.upstream.get(controller.diagnosis, {}) if tick is not None else {} for tick in ticks]
            u_carried = controller.step(k, taken_readings, given, self.runs, alive)
            wire.answer(CONTROLLER, ticks, controller.signals, controller.raw, alive, saturate=False)
            self.held = np.where(controller.commanded, u_carried, self.held)
        taken = [wire.inputs(k, e.name, alive, (readings, u_carried)) for e in self.estimators]
        values = self._estimates(k, [(y, np.nan_to_num(u), ~np.isnan(u)) for _, y, u in taken], alive)
        if values is None:
            return
        for e, (ticks, _, _) in zip(self.estimators, taken):
            wire.answer(e.name, ticks, e.signals, e.raw, alive, saturate=True)
        rows = np.flatnonzero(alive)
        wire.truth(k, x, self.state_names, [(*a, *b) for a, b in zip(active, wire.active(t))], rows.tolist(), values)
        self._advance(k, t, rows, self.held, alive)

    def _estimates(
        self, k: int, inputs: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], alive: np.ndarray
    ) -> list[np.ndarray] | None:
        """Each estimator's signals of tick k as its frames carry them, from its ``inputs``: its
        readings, commands and which came (``Stepped.step``); None: every run left."""
        runs = self.runs
        try:
            given = {
                e.name: (np.where(alive[:, None], readings, 0.0), u_cmd, commanded)
                for e, (readings, u_cmd, commanded) in zip(self.estimators, inputs, strict=True)
            }
            found: dict[str, np.ndarray] = {}
            for group in self.stepped:
                found.update(zip((e.name for e in group.members), group.step([given[e.name] for e in group.members])))
            values = [found[e.name] for e in self.estimators]
        except Exception as error:  # noqa: BLE001 (an estimator's own code: every run goes alone, as each ends alone)
            for r in np.flatnonzero(alive):
                runs[r].leave(k, f"an estimator raised {type(error).__name__}: {error}")
            alive[:] = False
            return None
        if self.controller is not None and self.controller.diagnosis:
            e, v = next((e, v) for e, v in zip(self.estimators, values) if e.name == self.controller.diagnosis)
            self.report = (e.signals, v)
        for e, v in zip(self.estimators, values):
            bad = alive & np.isnan(v).any(axis=1)
            for row in map(int, np.flatnonzero(bad)):
                failed = e.failed.get(row)
                why = (
                    f"estimator {e.name} raised {failed}"
                    if failed
                    else f"estimator {e.name}: an estimate that is not a number"
                )
                runs[row].leave(k, why)
            alive &= ~bad
        return values

    def _advance(self, k: int, t: float, rows: np.ndarray, u_cmd: np.ndarray, alive: np.ndarray) -> None:
        """Each run's commands through its actuator faults into the physics of the runs, over tick k."""
        runs = self.runs
        u_eff, _ = fm.FaultInjector.actuators_batch([runs[r].source.faults for r in rows.tolist()], u_cmd[rows], t)
        d = self.disturbance(rows, t)
        finite = np.isfinite(u_eff).all(axis=1)
        for i in np.flatnonzero(~finite).tolist():
            try:
                runs[rows[i]].source.check_inputs(k, u_eff[i])
            except CosimError as error:  # its own error, as alone
                runs[rows[i]].leave(k, str(error))
                alive[rows[i]] = False
        for r, why in self.physics.step(rows[finite], u_eff[finite], d[finite]).items():
            runs[r].leave(k, f"the physics failed: {why}")
            alive[r] = False

    def _check(
        self, k: int, alive: np.ndarray, values: np.ndarray, bounds: tuple[np.ndarray, np.ndarray] | None, why: str
    ) -> None:
        _leave_outside(k, alive, values, bounds, self.runs, why)


def _leave_outside(
    k: int,
    alive: np.ndarray,
    values: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray] | None,
    runs: Sequence[_Run],
    why: str,
) -> None:
    """Runs whose ``values`` leave ``bounds`` (None: are not finite) leave the batch at tick k."""
    ok = (
        np.isfinite(values).all(axis=1)
        if bounds is None
        else ((bounds[0] <= values) & (values <= bounds[1])).all(axis=1)
    )
    for r in map(int, np.flatnonzero(alive & ~ok)):
        runs[r].leave(k, why)
    alive &= ok
