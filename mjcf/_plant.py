"""What a plant module declares beside its MJCF model.

Each plant is an MJCF file paired with one small module (dm_control suite style) that names its
sensors, actuators and state, gives their units and the ranges the CAN codec needs, and lists the
physical parameters with their sources. Physics lives in the XML; nothing here integrates anything.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim.bus.signals import Channel

MODEL_DIR = Path(__file__).resolve().parent


@dataclass(frozen=True)
class Parameter:
    """A physical parameter with its unit and where its value comes from."""

    value: float
    unit: str
    source: str


@dataclass(frozen=True)
class PlantInfo:
    """Everything the testbed needs to know about a plant besides its physics.

    ``model_file`` is the MJCF file, in ``mjcf/`` or, for a plant of one's own, an absolute path.
    ``states`` name the components of the MuJoCo state [qpos, qvel, act] in that order, or, with
    ``state_tendons``, the lengths of those tendons.
    ``sensors`` and ``actuators`` name MuJoCo sensors and actuators of the model (same names).
    ``disturbances`` name the MuJoCo actuators that model unknown inputs (a leak, a current): the
    scenario drives them, but they travel on no bus and no estimator knows their value.
    ``state_tendons``, when given, name fixed tendons whose lengths are the plant's state (truth,
    initial state, linear model): the other MuJoCo coordinates are fast internal dynamics (flows
    that settle within a timestep, cumulative volumes that nothing depends on), eliminated in
    linearization by their quasi-static limit (see ``cosim.plant.physics``).
    ``passive_forces``, when given, builds the forces a compiled model needs that its MJCF cannot
    express (the vessel's body-frame damping, ``mjcf._body_damping.forces``): called once with the
    model, it returns a function f(model, data) that adds them to ``data.qfrc_passive`` of that
    model and leaves any other model alone (or None). ``cosim.plant.physics`` makes f MuJoCo's
    passive-force callback (``mjcb_passive``, process-wide: MuJoCo calls it for every model stepped
    meanwhile) for the duration of the plant's own MuJoCo calls only, and restores the previous one.
    ``design_keyframe``, when given, is the keyframe at which the estimators' and controllers' linear
    model is taken (its state and ctrl are the operating point), where it differs from the initial
    state ``keyframe``: the vessel cruises from its initial state but is designed on, as the paper
    does, the linearization at rest (ν = 0, no Coriolis terms, body and earth frames aligned).
    ``drift_left_out``, when given, says why the design model is the plain linearization at the
    operating point although that is no equilibrium of its inputs (the three-tank's, which the paper
    linearizes there); by default such a point gets an affine model, its drift kept
    (``cosim.plant.equilibrium``). The run says which, either way.
    ``disturbance_models`` are the plant's random environments by name (a sea state): each is called
    as ``model(rng, **params)`` with a seeded numpy Generator and returns b(t), a function of time
    giving all the ``disturbances`` at once (shape (len(disturbances),)); it raises ValueError
    naming a bad parameter. Its class may offer ``batched(realizations)``: b(t) of K realizations
    as (K, len(disturbances)), each row bit for bit its own (a batch's runs; None where it cannot).
    """

    name: str
    description: str
    model_file: str
    states: tuple[Channel, ...]
    sensors: tuple[Channel, ...]
    actuators: tuple[Channel, ...]
    parameters: dict[str, Parameter] = field(default_factory=dict)
    keyframe: str = "rest"
    disturbances: tuple[Channel, ...] = ()
    state_tendons: tuple[str, ...] = ()
    passive_forces: Callable[[Any], Callable[[Any, Any], None] | None] | None = None
    disturbance_models: dict[str, Callable[..., Callable[[float], Any]]] = field(default_factory=dict)
    design_keyframe: str = ""
    drift_left_out: str = ""

    @property
    def model_path(self) -> Path:
        return MODEL_DIR / self.model_file

    def sensor(self, name: str) -> Channel:
        return _lookup(self.sensors, name, "sensor", self.name)

    def actuator(self, name: str) -> Channel:
        return _lookup(self.actuators, name, "actuator", self.name)

    def state(self, name: str) -> Channel:
        return _lookup(self.states, name, "state", self.name)

    def disturbance(self, name: str) -> Channel:
        return _lookup(self.disturbances, name, "disturbance input", self.name)


def _lookup(channels: tuple[Channel, ...], name: str, kind: str, plant: str) -> Channel:
    for channel in channels:
        if channel.name == name:
            return channel
    known = ", ".join(c.name for c in channels)
    raise KeyError(f"plant {plant!r} has no {kind} {name!r} (it has: {known})")
