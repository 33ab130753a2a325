"""What a run is built from, fixed before tick 0: the plan.

``RunPlan.build`` takes a loaded scenario (with command-line overrides), linearizes its plant at
its operating point (MuJoCo itself, ``cosim.plant``), designs every estimator and the controller on
that model (through the design cache), builds the run's CAN database and says what the log's
``cosim.run`` record will hold. Nothing in a plan changes while the run goes; what does (the
plant's state, the faults' random streams) lives in the tick source built from it
(``cosim.run.loop.PlantSource``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import estimators
import faults as fm
from cosim import design_cache, progress
from cosim.blas import one_thread
from cosim.bus.codec import CONTROL, CONTROLLER, PLANT, RUNNER, Codec
from cosim.bus.control_frames import ControlAuth, control_keys
from cosim.bus.keys import derive_key, run_secret
from cosim.bus.registry import Registration
from cosim.bus.secoc import SecOC
from cosim.bus.transport import BusConfig
from cosim.errors import ModelError, ScenarioError
from cosim.extras import missing_extra
from cosim.log.metadata import (
    ControllerRecord,
    DiagnosticRecord,
    EstimatorRecord,
    FaultRecord,
    RunRecord,
    ScenarioRecord,
)
from cosim.log.writer import LogSink, RecordSink
from cosim.plant import Plant, build_plant
from cosim.plant.fmu_model import is_fmu
from cosim.run.arbitration import Arbitration, build_traffic
from cosim.run.busfaults import BusFaultStage
from cosim.run.detector import IntrusionDetector
from cosim.run.node import NodeSpec
from cosim.run.session import Session, Timing
from cosim.scenario import LoadedScenario, Scenario, build_faults
from cosim.scenario.faults import BiasSpec, build_bus_faults
from cosim.scenario.load import timing_warnings
from estimators import Diagnostic, Estimator, LinearModel, ParameterError
from estimators import controller as controllers
from estimators.design import fault_rejectable


def build_estimators(
    s: Scenario, model: LinearModel, source: str, continuous: LinearModel | None = None
) -> dict[str, Estimator]:
    """Each estimator of the scenario, designed on ``model`` (discrete time), or on ``continuous``
    (the continuous-time linearization) for the kinds that integrate their own ODE."""
    built = {}
    for i, spec in enumerate(s.estimators):
        try:
            kind = estimators.ESTIMATORS[spec.kind]
            chosen = continuous if kind.continuous else model
            if chosen is None:
                raise ParameterError("model", f"{spec.kind} needs the continuous-time model")
            with progress.step(f"estimator {spec.name} ({kind.kind}), {i + 1} of {len(s.estimators)}"):
                built[spec.name] = design_cache.create(spec.kind, chosen, spec.params, s.sample_time)
        except ParameterError as error:
            raise ScenarioError(f"{source}: estimators[{i}] ({spec.name}): params.{error}") from None
        except Exception as error:  # noqa: BLE001 (a plugin's design may raise anything: one line, not its traceback)
            missing = (
                missing_extra(error, f"{source}: estimators[{i}] ({spec.name}, {spec.kind})")
                if isinstance(error, ImportError)
                else None
            )
            if missing is not None:  # its design needs an extra's package (the LMI solvers)
                raise missing from None
            if estimators.ESTIMATORS.origin(spec.kind).source == "built-in":
                raise  # a bug of ours: its traceback
            raise ScenarioError(
                f"{source}: estimators[{i}] ({spec.name}, {spec.kind}): its design raised {plugin_error(error)}"
            ) from None
    return built


def plugin_error(error: BaseException) -> str:
    """What a plugin's code raised, in a line: the exception and where in the plugin's own code
    (the innermost frame outside cosim, the libraries and the standard library)."""
    import sysconfig
    import traceback

    ours = [str(Path(estimators.__file__).parent.parent), *sysconfig.get_paths().values()]
    frames = [f for f in traceback.extract_tb(error.__traceback__) if not f.filename.startswith(tuple(ours))]
    where = f" at {frames[-1].filename}:{frames[-1].lineno}" if frames else ""
    return f"{type(error).__name__}: {error}{where}"


def build_controller(
    s: Scenario, model: LinearModel, source: str, continuous: LinearModel | None = None
) -> controllers.Controller | None:
    """The scenario's controller on the plant's linear model, with its parameters checked."""
    if s.controller is None:
        return None
    kind = controllers.CONTROLLERS[s.controller.kind]
    chosen = continuous if kind.continuous else model
    if chosen is None:
        raise ScenarioError(f"{source}: controller: {s.controller.kind} needs the continuous-time model")
    try:
        with progress.step(f"controller ({s.controller.kind})"):
            return kind.from_params(chosen, s.controller.params, s.sample_time)
    except ParameterError as error:
        raise ScenarioError(f"{source}: controller.params.{error}") from None


def design_warnings(s: Scenario, built: dict[str, Estimator]) -> list[str]:
    """Warnings about scenario faults that an estimator cannot reject by design: a constant bias
    whose direction lies in Im(Y) (TAC 2024 Remark 4, CDC 2016 Remark 2), after those about the
    faults' timing."""
    found = timing_warnings(s)
    for spec in s.faults:
        if not isinstance(spec, BiasSpec):
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
                found.append(
                    f"estimator {name}: the bias {spec.name or 'fault'} {np.round(phi, 6).tolist()} lies in Im(Y), so "
                    "no "
                    "choice of pseudoinverse weights can reject it (TAC 2024 Remark 4)"
                )
    return found


def model_users(s: Scenario) -> list[str]:
    """Who needs a linear model of the plant: the estimators and the controller, as the scenario names them."""
    users = [f"estimators[{i}] ({e.name}, {e.kind})" for i, e in enumerate(s.estimators)]
    return users + ([f"controller ({s.controller.kind})"] if s.controller is not None else [])


def _linearizations(s: Scenario, plant: Any, source: str) -> tuple[LinearModel | None, LinearModel | None]:
    """The plant's discrete- and continuous-time linear models at its operating point (its design
    keyframe if it has one). An FMU plant is linearized only when an estimator or the controller
    needs a model (or the scenario gives its design model): else a co-simulation-only FMU could not run at all."""
    users = model_users(s)
    if is_fmu(s.plant.model) and not users and s.plant.state_space is None:
        return None, None
    if s.plant_info.design_keyframe:
        if not isinstance(plant, Plant):  # keyframes are MuJoCo's: a state-space plant has none
            raise ScenarioError(f"{source}: a state-space plant has no design keyframe")
        plant.reset(keyframe=s.plant_info.design_keyframe)
    elif is_fmu(s.plant.model) and s.plant.initial_state:  # an FMU's start point: its start values as the run sets them
        plant.reset(s.plant.initial_state)
    try:
        with progress.step("linearizing the plant at its operating point"):
            model = plant.linearize()
    except ModelError as error:
        raise ScenarioError(f"{source}: {users[0]} needs a linear model of the plant: {error}") from None
    needs_continuous = any(estimators.ESTIMATORS[e.kind].continuous for e in s.estimators) or (
        s.controller is not None and controllers.CONTROLLERS[s.controller.kind].continuous
    )
    try:  # computed even when no estimator needs it: the log records it, for replay to design new ones on
        continuous: LinearModel | None = plant.linearize(continuous=True)
    except ModelError:  # a discrete-time state-space plant has none
        if needs_continuous:
            raise
        continuous = None
    return model, continuous


def _close(plant: Any) -> list[Any]:
    """Free a plant the plan is done with (an FMU's instance), and what it said."""
    close = getattr(plant, "close", None)
    if close is not None:
        close()
    take = getattr(plant, "take_messages", None)
    return take() if take is not None else []


def first_tick_at(s: Scenario, start: float) -> int:
    """The first tick k with t_k >= start: where a fault starting at ``start`` is first active."""
    k = max(0, math.ceil(start / s.sample_time) - 1)
    while s.time(k) < start:
        k += 1
    return k


def fault_record(fault: fm.Fault, s: Scenario) -> FaultRecord:
    """What the log says about one fault: its window and the signals it acts on."""
    signals = s.actuators if isinstance(fault, fm.ActuatorFault) else s.sensors
    return FaultRecord(
        fault.label,
        fault.kind,
        fault.start,
        fault.end if np.isfinite(fault.end) else None,
        fault.targets() if isinstance(fault, fm.BusFault) else [signals[c] for c in fault.channels],
    )


def diagnostic_records(channels: list[Diagnostic]) -> dict[str, DiagnosticRecord]:
    """What the log says about each diagnostic signal."""
    return {d.name: DiagnosticRecord(d.kind.value, d.target, d.unit) for d in channels}


def estimator_record(
    codec: Codec, name: str, kind: str, params: dict[str, Any], estimator: Estimator
) -> EstimatorRecord:
    """The ``cosim.run`` entry of one estimator: designed ``estimator`` of ``kind``, given ``params``."""
    model = estimator.model
    diagnostics = diagnostic_records(estimators.ESTIMATORS[kind].diagnostic_channels(model.states, model.outputs))
    declared = str(getattr(type(estimator), "kind", "") or "")
    return EstimatorRecord(
        kind,
        [m.name for m in codec.data_messages(name)],
        list(model.states),
        {**params, **estimator.design_params()},
        model.to_dict(),
        diagnostics,
        estimator.isolation_targets(),
        declared if declared != kind else "",
    )


def bus_record(s: Scenario) -> dict[str, Any]:
    """The run record's ``bus``: its settings, those at their default left out (so that the log of
    an ideal bus is what it always was)."""
    bus = s.bus
    traffic = [t.model_dump(exclude={"end"}) | {"end": t.end if math.isfinite(t.end) else None} for t in bus.traffic]
    return {
        "interface": bus.interface,
        "fd": bus.fd,
        "bitrate": bus.bitrate,
        "data_bitrate": bus.data_bitrate,
        **({"timing": bus.timing} if bus.timing != "ideal" else {}),
        **({"authentication": bus.authentication} if bus.authentication != "none" else {}),
        **({"intrusion_detector": True} if bus.intrusion_detector else {}),
        **({"traffic": traffic} if traffic else {}),
    }


def channel_units(s: Scenario) -> dict[str, dict[str, str]]:
    """The unit of every channel the recorder writes, by table."""
    sensors, actuators, states = s.channels()
    return {
        "states": {c.name: c.unit for c in states},
        "sensors": {c.name: c.unit for c in sensors},
        "actuators": {c.name: c.unit for c in actuators},
        "disturbances": {c.name: c.unit for c in s.plant_info.disturbances},
    }


@dataclass(frozen=True, kw_only=True)
class RunPlan:
    """One run of a scenario, designed: everything that is fixed before tick 0."""

    loaded: LoadedScenario
    scenario: Scenario
    state_names: tuple[str, ...]
    model: LinearModel | None
    """The discrete-time linearization the estimators and the controller are designed on (None: an
    FMU plant that none of them needs a model of)."""
    continuous_model: LinearModel | None
    """The continuous-time one (None for a discrete-time state-space plant)."""
    estimators: dict[str, Estimator]
    controller: controllers.Controller | None
    codec: Codec
    warnings: tuple[str, ...]
    faults: tuple[FaultRecord, ...]
    onset_tick: int | None
    units: dict[str, dict[str, str]]
    operating_point: str = ""
    """Where the plant's linear model is taken, where that is not simply its operating point as it
    stands (that is no equilibrium of its inputs): the equilibrium reached from it, an affine model
    with its drift, or why the drift is left out (``cosim.plant.equilibrium``); "" otherwise."""
    plant_messages: tuple[Any, ...] = ()
    """What an FMU plant logged or printed while the plan was made (``fmu_calls.FmuMessage``)."""
    secret: bytes = field(default_factory=run_secret, repr=False)
    """The run's secret (``cosim.bus.keys``): random per plan, never logged; the control frames'
    keys, and SecOC's with ``[bus] authentication = "secoc"``, derive from it."""

    @classmethod
    def build(cls, loaded: LoadedScenario, seed: int | None = None, **overrides: Any) -> RunPlan:
        """The plan of ``loaded`` with ``seed`` and ``overrides`` (see ``Scenario.with_overrides``),
        validated like the file; a ScenarioError names whatever cannot be built. Built on one BLAS
        thread: the same linearization and designs on any machine (``cosim.blas.one_thread``)."""
        with one_thread():
            return cls._build(loaded, seed, **overrides)

    @classmethod
    def _build(cls, loaded: LoadedScenario, seed: int | None, **overrides: Any) -> RunPlan:
        try:
            s = loaded.scenario.with_overrides(seed=seed, **overrides)
        except ScenarioError as error:
            raise ScenarioError(f"{loaded.source}: {error}") from None
        try:
            with progress.step(f"loading the plant {s.plant.model}"):
                plant = build_plant(s)
        except ModelError as error:
            raise ScenarioError(f"{loaded.source}: {error}") from None
        try:
            model, continuous = _linearizations(s, plant, loaded.source)
        finally:
            said = _close(plant)
        built = build_estimators(s, model, loaded.source, continuous) if model is not None else {}
        injector = build_faults(s)
        bus_faults = build_bus_faults(s)
        onset = min([f for f in [injector.first_onset, *(b.start for b in bus_faults)] if f is not None], default=None)
        return cls(
            loaded=loaded,
            scenario=s,
            state_names=tuple(plant.state_names),
            plant_messages=tuple(said),
            operating_point=getattr(plant, "operating_point", "") if model is not None else "",
            model=model,
            continuous_model=continuous,
            estimators=built,
            controller=build_controller(s, model, loaded.source, continuous) if model is not None else None,
            codec=s.codec(),
            warnings=tuple([*getattr(plant, "warnings", ()), *design_warnings(s, built)]),
            faults=tuple(fault_record(f, s) for f in [*injector.faults, *bus_faults]),
            onset_tick=None if onset is None else first_tick_at(s, onset),
            units=channel_units(s),
        )

    @property
    def external_nodes(self) -> list[str]:
        """The nodes started by hand ('cosim node NAME --run ID')."""
        names = [e.name for e in self.scenario.estimators if e.external]
        c = self.scenario.controller
        return names + [CONTROLLER] if c is not None and c.external else names

    def node_spec(self, name: str, bus: BusConfig) -> NodeSpec:
        """What the node ``name`` (an estimator, or the controller) needs to run on ``bus``."""
        s = self.scenario
        if name == CONTROLLER and s.controller is not None and self.controller is not None:
            diagnosis = s.controller.diagnosis
            return NodeSpec(
                CONTROLLER,
                s.controller.kind,
                s.controller.params,
                self.controller.model,
                self.codec.dbc,
                bus,
                s.sample_time,
                {diagnosis: 1} if diagnosis else {},
                diagnosis,
                self.keys(CONTROLLER, [PLANT, *([diagnosis] if diagnosis else [])]),
                control_keys(self.secret, [CONTROLLER, RUNNER, *([diagnosis] if diagnosis else [])]),
            )
        spec = next(e for e in s.estimators if e.name == name)
        estimator = self.estimators[name]
        return NodeSpec(
            name,
            spec.kind,
            {**spec.params, **estimator.node_params()},
            estimator.model,
            self.codec.dbc,
            bus,
            s.sample_time,
            {CONTROLLER: 0} if s.controller is not None else {},
            keys=self.keys(name, [PLANT, CONTROLLER]),
            control_keys=control_keys(
                self.secret, [name, RUNNER, *([CONTROLLER] if CONTROLLER in self.codec.node_ids else [])]
            ),
        )

    def keys(self, node: str, hears: list[str]) -> dict[str, str]:
        """A node's SecOC keys (hex): its own, to sign, and those of the senders it hears, to verify."""
        if not self.authenticated:
            return {}
        return {sender: derive_key(self.secret, sender).hex() for sender in [node, *hears]}

    def secoc(self) -> SecOC | None:
        """The runner's SecOC: every sender's key (it signs the plant's frames and verifies everyone's)."""
        if not self.authenticated:
            return None
        senders = {spec.sender for spec in self.codec.specs.values()}
        return SecOC.from_codec(self.codec, {sender: derive_key(self.secret, sender) for sender in senders})

    @property
    def authenticated(self) -> bool:
        """Whether the data frames carry SecOC (control frames are always authenticated)."""
        return self.scenario.bus.authentication == "secoc"

    def control(self) -> ControlAuth:
        """The runner's control-frame keys: its own, to sign NMT and SYNC, and every node's."""
        return ControlAuth.from_secret(self.codec, self.secret, [RUNNER, *self.codec.node_ids])

    def client_keys(self) -> dict[str, str]:
        """The control keys (hex) of the runner and of the participants a client may join as or
        hear, for the run registry: the declared clients and the controller node."""
        clients = [c.name for c in self.scenario.clients]
        controller = [CONTROLLER] if CONTROLLER in self.codec.node_ids else []
        return control_keys(self.secret, [RUNNER, *clients, *controller])

    @property
    def senders(self) -> list[str]:
        """The participants whose frames the runner accounts for: estimators, clients, controller node."""
        s = self.scenario
        return [*self.estimators, *(c.name for c in s.clients), *([CONTROLLER] if self.controller is not None else [])]

    @property
    def own_senders(self) -> tuple[str, ...]:
        """The DBC nodes whose frames the runner itself sends (the controller's too in an open loop)."""
        return (RUNNER, PLANT) if self.controller is not None else (RUNNER, PLANT, CONTROLLER)

    def session(
        self,
        out: Path | None,
        bus: BusConfig,
        registration: Registration | None = None,
        sink: LogSink | RecordSink | None = None,
    ) -> Session:
        """The session of a run of this plan on ``bus``, logging to ``out`` (and to ``sink``; with
        ``out`` None, to ``sink`` alone)."""
        s = self.scenario
        closed_loop = self.controller is not None
        bus_faults = build_bus_faults(s)
        return Session(
            out,
            bus,
            self.codec,
            Timing(s.sample_time, s.timing.mode, s.timing.speed, s.timing.node_timeout, s.timing.join_timeout),
            recorder={
                "states": self.state_names,
                "sensors": s.sensors,
                "actuators": s.actuators,
                "units": self.units,
                "disturbances": s.disturbance_inputs,
            },
            own_senders=self.own_senders,
            commands=closed_loop,
            registration=registration,
            sink=sink,
            arbitration=self.arbitration(bus_faults),
            bus_faults=self.bus_fault_stage(bus_faults),
            secoc=self.secoc(),
            control=self.control(),
            detector=self.intrusion_detector(),
        )

    def arbitration(self, bus_faults: list[fm.BusFault]) -> Arbitration | None:
        """A run's simulated wire (arbitrated timing; None: ideal), its babbling nodes among
        ``bus_faults`` (``build_bus_faults``, the list its stage gets) on it."""
        s = self.scenario
        if s.bus.timing != "arbitrated":
            return None
        babblers = [f for f in bus_faults if isinstance(f, fm.BabblingNode)]
        traffic = build_traffic(s, babblers)
        return Arbitration(self.codec, s.bus.bitrate, s.bus.data_bitrate, s.dt_ns, traffic, self.authenticated)

    def bus_fault_stage(self, bus_faults: list[fm.BusFault]) -> BusFaultStage | None:
        """A run's bus faults between the runner and the receivers (None: it has none)."""
        s = self.scenario
        if not bus_faults:
            return None
        arbitrated = s.bus.timing == "arbitrated"
        return BusFaultStage(
            self.codec, bus_faults, s.seed, s.dt_ns, s.bus.bitrate, arbitrated, authenticated=self.authenticated
        )

    def intrusion_detector(self) -> IntrusionDetector | None:
        """A run's key-less intrusion detector (None: ``[bus] intrusion_detector`` is off)."""
        s = self.scenario
        if not s.bus.intrusion_detector:
            return None
        return IntrusionDetector(self.codec, s.dt_ns, frozenset(t.id for t in s.bus.traffic))

    def run_record(self, start_time_ns: int | None = None) -> RunRecord:
        """The log's ``cosim.run`` record; ``start_time_ns``: the run's wall-clock start (UTC, ns)."""
        s, codec = self.scenario, self.codec
        controller = None
        if s.controller is not None and self.controller is not None:
            kind = controllers.CONTROLLERS[s.controller.kind]
            controller = ControllerRecord(
                s.controller.kind,
                s.controller.params,
                s.controller.diagnosis,
                [m.name for m in codec.data_messages(CONTROLLER)],
                self.controller.model.to_dict(),
                [m.name for m in codec.messages(role=CONTROL)],
                diagnostic_records(kind.diagnostic_channels(s.actuators, s.sensors)),
            )
        return RunRecord(
            scenario=s.name,
            source=self.loaded.source,
            seed=s.seed,
            sample_time=s.sample_time,
            duration=s.duration,
            ticks=s.ticks,
            plant=s.plant.model,
            states=list(self.state_names),
            sensors=list(s.sensors),
            actuators=list(s.actuators),
            disturbances=list(s.disturbance_inputs),
            estimators={
                spec.name: estimator_record(codec, spec.name, spec.kind, spec.params, self.estimators[spec.name])
                for spec in s.estimators
            },
            model=None if self.model is None else self.model.to_dict(),
            continuous_model=None if self.continuous_model is None else self.continuous_model.to_dict(),
            clients={
                c.name: {"lockstep": c.lockstep, "messages": [m.name for m in codec.data_messages(c.name)]}
                for c in s.clients
            },
            controller=controller,
            fault_onset=min((f.start for f in self.faults if f.start is not None), default=None),
            fault_onset_tick=self.onset_tick,
            faults=list(self.faults),
            bus=bus_record(s),
            timing=s.timing.model_dump(),
            start_time_ns=start_time_ns,
            operating_point=self.operating_point or None,
        )

    def scenario_record(self) -> ScenarioRecord:
        """The log's ``cosim.scenario`` record."""
        settings = json.dumps([[key, value] for key, value in self.loaded.settings])
        return ScenarioRecord(self.loaded.source, self.loaded.text, self.scenario.model_dump_json(), settings)
