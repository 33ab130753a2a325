"""``cosim fmu SCENARIO --system``: a scenario as a system of co-simulation FMUs that another engine
runs, e.g. the Open Simulation Platform's libcosim.

The system is the run without its bus: the plant's FMU (the runner's side: the plant, its faults,
noise and disturbances, and in an open loop the scenario's inputs), one FMU per estimator and, in a
closed loop, the controller's, wired output to input as the run's frames carry the values (the
plant's readings to the estimators and the controller, the commands to the plant and the
estimators, the diagnosis node's report to the controller). Each FMU carries the bus's arithmetic
(``cosim.run.fmu_interface.carried``): a value leaves it as its frame carries it, quantized on
classic CAN, an estimate saturated to its signal's range, so that every estimator's outputs equal
the estimates its node logged, tick by tick.

Timing. Every FMU answers the values it reads at the start of a step, as a fixed-step (Jacobi)
master hands them over: the plant's outputs at t_k are tick k's readings, an estimator's at t_k+1
its answer to tick k. In an open loop the system's step is τ. In a closed loop the controller must
answer tick k before the plant moves and the estimators read its commands, so the step is τ/2:
the controller works in the first half of each tick, the plant and the estimators in the second
(their ``phase`` ½), and a step of any other size is refused.

What a system cannot express (frames themselves: bus faults and attacks, arbitration, SecOC, the
intrusion detector; wall-clock timing; client programs and nodes started by hand) is refused in one
line (``refusal``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim import __version__
from cosim.bus.codec import COMMAND, CONTROLLER
from cosim.errors import CosimError
from cosim.scenario import LoadedScenario, Scenario
from cosim.scenario.faults import build_bus_faults

#: The plant's component (and FMU) name; the controller's is ``CONTROLLER``, an estimator's its own.
PLANT = "plant"
OPEN_LOOP = "one sample time: each FMU answers every tick's values once"
CLOSED_LOOP = (
    "half the sample time: the controller answers in a tick's first half, the plant and estimators in its second"
)


@dataclass(frozen=True)
class Component:
    """One FMU of the system: its instance name, its ``content.json`` and the files beside it."""

    name: str
    content: dict[str, Any]
    files: dict[str, Path] = field(default_factory=dict)
    platforms: set[str] | None = None

    @property
    def outputs(self) -> list[str]:
        """Its outputs' names: the plant's readings (and an open loop's commands) and states, an
        estimator's estimate and diagnostics, the controller's commands and diagnostics."""
        c = self.content
        if c["slave"] == "plant":
            commands = c["actuators"] if not c["system"]["closed_loop"] else []
            return [v["name"] for v in [*commands, *c["sensors"]]] + [f"state.{v['name']}" for v in c["states"]]
        if c["slave"] == "controller":
            return [v["name"] for v in [*c["commands"], *c["diagnostics"]]]
        return [v["name"] for v in c["outputs"]]


@dataclass(frozen=True)
class Connection:
    """An output of one component wired to an input of another."""

    source: str
    output: str
    target: str
    input: str


@dataclass(frozen=True)
class System:
    """A scenario as components and connections, stepped by ``step`` from 0 to ``duration``."""

    name: str
    description: str
    step: float
    duration: float
    components: list[Component]
    connections: list[Connection]


def refusal(s: Scenario) -> str | None:
    """What of the scenario a system of FMUs, connected value to value, cannot express (None: nothing)."""
    found = []
    if bus_faults := build_bus_faults(s):
        found.append(f"bus faults and attacks ({', '.join(f.label for f in bus_faults)})")
    if s.bus.timing == "arbitrated" or s.bus.traffic:
        found.append("arbitrated timing and other nodes' traffic ([bus] timing, traffic)")
    if s.bus.authentication != "none":
        found.append("SecOC ([bus] authentication)")
    if s.bus.intrusion_detector:
        found.append("the intrusion detector ([bus] intrusion_detector)")
    if s.timing.mode != "lockstep":
        found.append(f"{s.timing.mode} timing ([timing] mode)")
    if s.clients:
        found.append(f"client programs ([[clients]] {', '.join(c.name for c in s.clients)})")
    external = [e.name for e in s.estimators if e.external]
    if s.controller is not None and s.controller.external:
        external.append(CONTROLLER)
    if external:
        found.append(f"nodes started by hand (external: {', '.join(external)})")
    if not found:
        return None
    return (
        f"{'; '.join(found)}: they act on the bus's frames or its timing, which a system of FMUs connected "
        "value to value does not have; run it with cosim run"
    )


def build(loaded: LoadedScenario) -> System:
    """The scenario as a system; a CosimError in one line for one it cannot express."""
    from cosim.run.fmu_estimator import content_of
    from cosim.run.fmu_export import exported, plant_files
    from cosim.run.plan import RunPlan

    s = loaded.scenario
    if (why := refusal(s)) is not None:
        raise CosimError(f"cosim fmu --system: {loaded.source} cannot be a system of FMUs: {why}")
    _check_components(s)
    plan = RunPlan.build(loaded)
    closed = s.controller is not None
    step = s.sample_time / 2 if closed else s.sample_time

    def on_bus(phase: float) -> dict[str, Any]:
        """The ``system`` of a component's content (``cosim.run.fmu_interface.Slave``)."""
        why = CLOSED_LOOP if closed else OPEN_LOOP
        return {"step": step, "phase": phase, "closed_loop": closed, "why": why, "dbc": plan.codec.dbc}

    late = 0.5 if closed else 0.0  # in a closed loop the plant and the estimators act after the controller
    files, platforms = plant_files(s)
    components = [Component(PLANT, {**exported(loaded), "system": on_bus(late)}, files, platforms)]
    for spec in s.estimators:
        content, shipped = content_of(plan, spec.name)
        components.append(Component(spec.name, {**content, "system": on_bus(late)}, shipped))
    if closed:
        components.append(Component(CONTROLLER, {**controller_content(plan), "system": on_bus(0.0)}))
    return System(s.name, s.description, step, s.duration, components, connections(components))


def _check_components(s: Scenario) -> None:
    """Each component has a name of its own (an estimator named like the plant would overwrite its
    FMU), and a plugin controller does not travel in the system (only built-in kinds do)."""
    from estimators.controller import CONTROLLERS

    for i, e in enumerate(s.estimators):
        if e.name in (PLANT, CONTROLLER):
            raise CosimError(
                f"cosim fmu --system: estimator {e.name!r} has the name of the system's {e.name} component: rename it "
                f"(--set 'estimators[{i}].name=\"...\"')"
            )

    if s.controller is not None and CONTROLLERS.origin(s.controller.kind).source != "built-in":
        raise CosimError(
            f"cosim fmu --system: controller {s.controller.kind!r} is not a built-in kind; the system's controller FMU "
            "carries built-in controllers only"
        )


def controller_content(plan: Any) -> dict[str, Any]:
    """What the controller's FMU holds (``cosim.run.fmu_controller_slave``): its kind, parameters
    and design model, the readings it takes, the diagnosis node's signals it reads (its report),
    its commands (by actuator, in the order of the model's inputs) and its diagnostics."""
    from cosim.run.fmu_export import fmi_units, model_identifier, variable

    s, codec = plan.scenario, plan.codec
    assert s.controller is not None and plan.controller is not None
    model = plan.controller.model
    sensors, actuators, _ = s.channels()
    by_name = {c.name: c for c in [*sensors, *actuators]}
    sent = [
        (m.role, channel, signal)
        for m in codec.data_messages(CONTROLLER)
        for channel, signal in zip(m.channels, m.signals)
    ]
    signal_of = {channel.name: signal for role, channel, signal in sent if role == COMMAND}
    diagnosis = s.controller.diagnosis
    report = [
        {**variable(channel), "name": signal}
        for m in (codec.data_messages(diagnosis) if diagnosis else [])
        for channel, signal in zip(m.channels, m.signals)
    ]
    content = {
        "slave": "controller",
        "model_identifier": model_identifier(f"{s.name}_{CONTROLLER}"),
        "description": f"cosim controller ({s.controller.kind}) of scenario {s.name}, sample time {s.sample_time:g} s",
        "cosim_version": __version__,
        "kind": s.controller.kind,
        "params": s.controller.params,
        "model": model.to_dict(),
        "sample_time": s.sample_time,
        "duration": s.duration,
        "readings": [variable(by_name[n]) for n in model.outputs],
        "diagnosis": diagnosis,
        "report": report,
        "commands": [{**variable(by_name[n]), "signal": signal_of[n]} for n in model.inputs],
        "diagnostics": [{**variable(channel), "name": signal} for role, channel, signal in sent if role != COMMAND],
    }
    groups = ("readings", "report", "commands", "diagnostics")
    return {**content, "units": fmi_units(v for group in groups for v in content[group])}


def connections(components: list[Component]) -> list[Connection]:
    """How the components are wired: the plant's readings to every estimator and the controller,
    the commands (the plant's own in an open loop, else the controller's) to the estimators and
    the plant, the diagnosis node's outputs to the controller's report."""
    wires: list[Connection] = []
    closed = any(c.name == CONTROLLER for c in components)
    commander = CONTROLLER if closed else PLANT
    for component in components[1:]:
        content = component.content
        wires += [Connection(PLANT, v["name"], component.name, v["name"]) for v in content["readings"]]
        if component.name == CONTROLLER:
            diagnosis = content["diagnosis"]
            wires += [
                Connection(diagnosis, v["name"], CONTROLLER, f"{diagnosis}.{v['name']}") for v in content["report"]
            ]
            wires += [Connection(CONTROLLER, v["name"], PLANT, v["name"]) for v in content["commands"]]
        else:
            wires += [Connection(commander, v["name"], component.name, v["name"]) for v in content["commands"]]
    return wires
