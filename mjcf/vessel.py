"""The over-actuated surface vessel of Cristofaro & Johansen, Sec. 4 (paper 003).

Ship model (Sec. 4):

    η̇ = P(ψ) ν,        M ν̇ = −V(η, ν) + τ + Pᵀ(ψ) b(t),        τ = G u,

η = [x, y, ψ] (earth frame), ν = [u, v, r] (surge, sway, yaw rate in the body frame), M the inertia
matrix including added mass, V the Coriolis and damping terms (damping −D ν), b(t) an earth-frame
disturbance with |b(t)| ≤ ε = 5e6. Linearized at a heading ψ̄ (eq. (23)):

    Ẋ = A X + B τ + E(t),   A = [[0, P(ψ̄)], [0, −M⁻¹D]],   B = [[0], [M⁻¹]],   C = I₆.

The MJCF model ``vessel.xml`` holds the physics; its header explains how M, D and G are expressed
and what the world-frame added mass costs away from heading 0. This module gives the paper's
constants (``PAPER_M``, ``PAPER_D``, ``THRUSTERS``, ``thruster_matrix``, ``paper_model``,
``DISTURBANCE_BOUND``), names the plant's signals (``INFO``, with the body-frame damping the model relies on,
``mjcf._body_damping``, as its passive forces), and generates the environmental disturbance
b(t) (``EnvironmentDisturbance``, ``environment_disturbance``).

The plant's state is MuJoCo's [qpos, qvel] = [x, y, ψ, ẋ, ẏ, r]: earth-frame velocities, which
equal ν = [u, v, r] at ψ = 0 only (ẋ, ẏ = P(ψ) [u, v]). The sensors u, v are body-frame.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from mjcf import _body_damping
from mjcf._plant import Channel, Parameter, PlantInfo

_PAPER = "Cristofaro & Johansen, Sec. 4"

#: Inertia matrix M including added mass (Sec. 4), SI: kg, kg m, kg m^2, for ν = [u, v, r].
PAPER_M = 1e9 * np.array([[0.0068, 0.0, 0.0], [0.0, 0.0113, -0.0340], [0.0, -0.0340, 4.4524]])
#: Linear damping matrix D (Sec. 4), SI: kg/s, kg m/s, kg m^2/s. Not symmetric (D23 ≠ D32).
PAPER_D = 1e8 * np.array([[0.0008, 0.0, 0.0], [0.0, 0.0025, -0.0203], [0.0, -0.0340, 3.8481]])
#: Bound ε on the environmental disturbance |b(t)| (Sec. 4), N (and N m for the moment).
DISTURBANCE_BOUND = 5e6

MASS = 6e6  # kg, the paper's μ
LENGTH = 76.0  # m
WIDTH = 16.0  # m


class Thruster(NamedTuple):
    """A thruster at distance ``distance`` (m) and angle ``angle`` (rad) from the rotation point.

    ``azimuth`` thrusters give a surge and a sway force component (two inputs), tunnel thrusters a
    sway force only (one input). ``angle`` follows the paper's moment arms (Sec. 4):
    γ(x-force) = d sin φ, γ(y-force) = d cos φ, i.e. the thruster sits at body position
    (d cos φ, −d sin φ): φ is measured from the bow against the positive yaw sense.
    """

    name: str
    distance: float
    angle: float
    azimuth: bool
    source: str


#: The five thrusters (Sec. 4). d and φ1, φ2 are the paper's; φ3, φ4, φ5 are not given there and
#: are chosen here: all three forward on the centreline (φ = 0), the usual layout of a supply
#: vessel (bow azimuth T3 at 18.5 m, bow tunnels T4, T5 at 30 m and 35 m, inside the 38 m half
#: length), which keeps every thruster triple the paper's COFD observers use independent.
THRUSTERS = (
    Thruster("T1", 20.0, np.pi + 0.3, True, _PAPER),
    Thruster("T2", 20.0, np.pi - 0.3, True, _PAPER),
    Thruster("T3", 18.5, 0.0, True, f"d3 from {_PAPER}; φ3 = 0 chosen (bow, centreline)"),
    Thruster("T4", 30.0, 0.0, False, f"d4 from {_PAPER}; φ4 = 0 chosen (bow tunnel)"),
    Thruster("T5", 35.0, 0.0, False, f"d5 from {_PAPER}; φ5 = 0 chosen (bow tunnel)"),
)

#: The inputs u, in order: an x and a y force component per azimuth thruster, a y force per tunnel.
INPUTS = ("T1x", "T1y", "T2x", "T2y", "T3x", "T3y", "T4", "T5")


def thruster_position(thruster: Thruster) -> tuple[float, float]:
    """Body-frame position (x forward, y to port, z up) of a thruster, m: (d cos φ, −d sin φ)."""
    return thruster.distance * np.cos(thruster.angle), -thruster.distance * np.sin(thruster.angle)


def thruster_matrix(thrusters: tuple[Thruster, ...] = THRUSTERS) -> np.ndarray:
    """The thrust configuration matrix G of τ = G u (Sec. 4), shape (3, 8) for the five thrusters.

    Azimuth thruster s: columns [1, 0, γ_{2s−1}] and [0, 1, γ_{2s}] with γ_{2s−1} = d_s sin φ_s,
    γ_{2s} = d_s cos φ_s; tunnel thruster s: column [0, 1, χ_s] with χ_s = d_s cos φ_s.
    """
    columns = []
    for t in thrusters:
        if t.azimuth:
            columns.append([1.0, 0.0, t.distance * np.sin(t.angle)])
        columns.append([0.0, 1.0, t.distance * np.cos(t.angle)])
    return np.array(columns).T


def rotation(psi: float) -> np.ndarray:
    """P(ψ) of Sec. 4, shape (3, 3): η̇ = P(ψ) ν."""
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def paper_model(
    psi_bar: float = 0.0, M: np.ndarray = PAPER_M, D: np.ndarray = PAPER_D, G: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The linear model of eq. (23) at heading ψ̄, for X = [x, y, ψ, u, v, r].

    Returns (A, B_tau, B_u, C) with shapes (6, 6), (6, 3), (6, 8), (6, 6):
    A = [[0, P(ψ̄)], [0, −M⁻¹D]], B_tau = [[0], [M⁻¹]] (the paper's B, input τ),
    B_u = W = B_tau G (input u, Sec. 4), C = I₆.
    """
    G = thruster_matrix() if G is None else G
    Minv = np.linalg.inv(M)
    A = np.block([[np.zeros((3, 3)), rotation(psi_bar)], [np.zeros((3, 3)), -Minv @ D]])
    B_tau = np.vstack([np.zeros((3, 3)), Minv])
    return A, B_tau, B_tau @ G, np.eye(6)


def disturbance_matrix(psi_bar: float = 0.0, M: np.ndarray = PAPER_M) -> np.ndarray:
    """The direction of b in eq. (23): E(t) = [[0], [M⁻¹ Pᵀ(ψ̄)]] b(t), shape (6, 3)."""
    return np.vstack([np.zeros((3, 3)), np.linalg.inv(M) @ rotation(psi_bar).T])


# The plant ------------------------------------------------------------------------------------

X_G = PAPER_M[1, 2] / MASS  # m: centre-of-mass offset that carries the sway-yaw coupling M23
HULL_YAW_INERTIA = MASS * (LENGTH**2 + WIDTH**2) / 12.0  # kg m^2, a 76 m x 16 m box about its centre

PARAMETERS = {
    "mass": Parameter(MASS, "kg", f"{_PAPER} (μ)"),
    "length": Parameter(LENGTH, "m", _PAPER),
    "width": Parameter(WIDTH, "m", _PAPER),
    "x_g": Parameter(X_G, "m", "M23 / mass: the rigid offset that gives M's sway-yaw coupling (vessel.xml, INERTIA)"),
    "hull_yaw_inertia": Parameter(
        HULL_YAW_INERTIA, "kg m^2", "mass (length^2 + width^2) / 12, a box about the centre of mass"
    ),
    "added_mass_x": Parameter(PAPER_M[0, 0] - MASS, "kg", "M11 - mass, armature of the x slide (world axis)"),
    "added_mass_y": Parameter(PAPER_M[1, 1] - MASS, "kg", "M22 - mass, armature of the y slide (world axis)"),
    "added_yaw_inertia": Parameter(
        PAPER_M[2, 2] - HULL_YAW_INERTIA - MASS * X_G**2,
        "kg m^2",
        "M33 - hull_yaw_inertia - mass x_g^2, armature of the heading hinge",
    ),
    **{f"M{i + 1}{j + 1}": Parameter(float(PAPER_M[i, j]), "SI", _PAPER) for i in range(3) for j in range(3)},
    **{f"D{i + 1}{j + 1}": Parameter(float(PAPER_D[i, j]), "SI", _PAPER) for i in range(3) for j in range(3)},
    **{f"d{k + 1}": Parameter(t.distance, "m", t.source) for k, t in enumerate(THRUSTERS)},
    **{f"phi{k + 1}": Parameter(t.angle, "rad", t.source) for k, t in enumerate(THRUSTERS)},
    "epsilon": Parameter(DISTURBANCE_BOUND, "N", f"{_PAPER}: bound on |b(t)|"),
}


def _position(name: str, description: str) -> Channel:
    # 1 mm over ±20 km: 26-bit signed integers.
    return Channel(name, "m", description, -2e4, 2e4, 1e-3)


def _heading(name: str, description: str) -> Channel:
    # 1 µrad over ±100 rad (about 16 turns; the hinge angle is not wrapped): 28 bits.
    return Channel(name, "rad", description, -100.0, 100.0, 1e-6)


def _speed(name: str, description: str, **kwargs: Any) -> Channel:
    # 10 µm/s over ±20 m/s (39 knots): 23 bits.
    return Channel(name, "m/s", description, -20.0, 20.0, 1e-5, **kwargs)


def _yaw_rate(name: str, description: str) -> Channel:
    # 0.1 µrad/s over ±1 rad/s: 24 bits.
    return Channel(name, "rad/s", description, -1.0, 1.0, 1e-7)


def _thrust(name: str, description: str) -> Channel:
    # 1 N over ±5 MN (the cruise thrust D ν0 allocates about 2e5 N per component): 24 bits.
    return Channel(name, "N", description, -5e6, 5e6, 1.0)


INFO = PlantInfo(
    name="vessel",
    description="Over-actuated surface vessel, 3 azimuth + 2 tunnel thrusters (Cristofaro & Johansen, Sec. 4)",
    model_file="vessel.xml",
    states=(
        _position("x", "earth-frame position of the body origin, x_G"),
        _position("y", "earth-frame position of the body origin, y_G"),
        _heading("psi", "heading ψ"),
        _speed("x_dot", "earth-frame velocity dx/dt (= surge u at ψ = 0)"),
        _speed("y_dot", "earth-frame velocity dy/dt (= sway v at ψ = 0)"),
        _yaw_rate("r", "yaw rate r = dψ/dt"),
    ),
    sensors=(
        _position("x", "earth-frame position x_G"),
        _position("y", "earth-frame position y_G"),
        _heading("psi", "heading ψ"),
        _speed("u", "surge velocity (body frame)", source="velocity", component=0),
        _speed("v", "sway velocity (body frame)", source="velocity", component=1),
        _yaw_rate("r", "yaw rate"),
    ),
    actuators=tuple(
        _thrust(
            name,
            f"{name[:2]} {'x (surge)' if name.endswith('x') else 'y (sway)'} thrust, body frame"
            if len(name) == 3
            else f"{name} tunnel thrust, y (sway), body frame",
        )
        for name in INPUTS
    ),
    parameters=PARAMETERS,
    disturbances=(
        Channel("b_x", "N", "environmental force b_x, earth frame", -DISTURBANCE_BOUND, DISTURBANCE_BOUND, 1.0),
        Channel("b_y", "N", "environmental force b_y, earth frame", -DISTURBANCE_BOUND, DISTURBANCE_BOUND, 1.0),
        Channel("b_n", "N m", "environmental yaw moment b_n", -DISTURBANCE_BOUND, DISTURBANCE_BOUND, 1.0),
    ),
    passive_forces=_body_damping.forces,  # the part of D that MJCF cannot express (vessel.xml, DAMPING)
    # [[disturbances]] model = "environment": current + waves, drawn from the scenario's seed.
    disturbance_models={"environment": lambda rng, **magnitudes: EnvironmentDisturbance.random(rng, **magnitudes)},
    design_keyframe="design",  # the paper's model (23): linearized at rest, heading 0 (vessel.xml)
)

#: The paper's initial state (Sec. 4), also the model's keyframe: η0 = (1, 1, 0), ν0 = (2.2, 1.9, 0).
INITIAL_ETA = (1.0, 1.0, 0.0)
INITIAL_NU = (2.2, 1.9, 0.0)


# The environmental disturbance b(t) -------------------------------------------------------------


@dataclass(frozen=True)
class EnvironmentDisturbance:
    """b(t) = b_c + Σ_i sin(ω_i t + ϕ_i) a_i [cos β_i(t), sin β_i(t), 0] + Σ_i n_i sin(ω_i t + θ_i) e_3.

    The earth-frame disturbance of Sec. 4: a constant current force ``current`` (N, along a fixed
    direction) plus wave components i of frequency ω_i (rad/s), force amplitude a_i (N) along a
    direction β_i(t) = β̄ + Δβ sin(Ω t + χ_i) that swings about the mean wave direction β̄, and yaw
    moment amplitude n_i (N m). Every component is bounded, so
    |b(t)| ≤ |b_c| + Σ_i hypot(a_i, n_i) = ``bound``, checked against ε = 5e6 on construction.
    """

    current: tuple[float, float, float]
    frequencies: tuple[float, ...]
    force_amplitudes: tuple[float, ...]
    force_phases: tuple[float, ...]
    moment_amplitudes: tuple[float, ...]
    moment_phases: tuple[float, ...]
    mean_direction: float
    swing: float
    swing_frequency: float
    swing_phases: tuple[float, ...]

    def __post_init__(self) -> None:
        if self.bound > DISTURBANCE_BOUND:
            raise ValueError(
                f"environment disturbance: |b| may reach {self.bound:.4g} > ε = {DISTURBANCE_BOUND:g}; "
                f"lower current, wave_force or wave_moment"
            )

    @property
    def bound(self) -> float:
        """The guaranteed bound on |b(t)| (triangle inequality over the components)."""
        return float(np.linalg.norm(self.current) + np.sum(np.hypot(self.force_amplitudes, self.moment_amplitudes)))

    @classmethod
    def random(
        cls,
        rng_or_seed: int | np.random.SeedSequence | np.random.Generator,
        *,
        current: float = 2e4,
        wave_force: float = 1e5,
        wave_moment: float = 1e6,
        wave_periods: tuple[float, float] = (6.0, 10.0),
        components: int = 3,
        swing: float = np.pi / 6,
        swing_period: float = 200.0,
    ) -> EnvironmentDisturbance:
        """A realization: current direction, mean wave direction, wave periods (uniform in
        ``wave_periods``, s) and phases drawn from the seed; ``wave_force`` (N) and ``wave_moment``
        (N m) are the sums of the components' amplitudes, split equally; the wave direction swings
        by ±``swing`` (rad) with period ``swing_period`` (s). A Generator is read, not advanced.
        """
        checks = {"current": current, "wave_force": wave_force, "wave_moment": wave_moment, "swing": swing}
        for name, value in checks.items():
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"environment disturbance: {name} = {value!r}; give a finite value >= 0")
        low, high = wave_periods
        if not 0 < low <= high or not swing_period > 0 or components < 1:
            raise ValueError(
                "environment disturbance: wave_periods must be 0 < low <= high, swing_period > 0, components >= 1"
            )
        if isinstance(rng_or_seed, np.random.Generator):
            rng = np.random.Generator(type(rng_or_seed.bit_generator)())
            rng.bit_generator.state = rng_or_seed.bit_generator.state
        else:
            rng = np.random.default_rng(rng_or_seed)
        heading = rng.uniform(-np.pi, np.pi)
        periods = rng.uniform(low, high, components)
        phases = rng.uniform(-np.pi, np.pi, (3, components))
        return cls(
            current=(current * np.cos(heading), current * np.sin(heading), 0.0),
            frequencies=tuple(2.0 * np.pi / periods),
            force_amplitudes=(wave_force / components,) * components,
            force_phases=tuple(phases[0]),
            moment_amplitudes=(wave_moment / components,) * components,
            moment_phases=tuple(phases[1]),
            mean_direction=float(rng.uniform(-np.pi, np.pi)),
            swing=float(swing),
            swing_frequency=2.0 * np.pi / swing_period,
            swing_phases=tuple(phases[2]),
        )

    @functools.cached_property
    def _arrays(self) -> tuple[np.ndarray, ...]:
        """The parameters as arrays, made once (a run asks for b(t) every tick)."""
        waves = (self.frequencies, self.swing_phases, self.force_amplitudes, self.force_phases)
        fields = (*waves, self.moment_amplitudes, self.moment_phases, self.current)
        return tuple(np.asarray(f, dtype=float) for f in fields)

    def __call__(self, t: float | np.ndarray) -> np.ndarray:
        """b(t) = [b_x, b_y, b_n] at time(s) ``t`` (s): shape (3,) for a scalar t, else (len(t), 3)."""
        w, swing_phases, force_amplitudes, force_phases, moment_amplitudes, moment_phases, current = self._arrays
        t = np.asarray(t, dtype=float)
        tt = t[..., None]  # components along the last axis
        beta = self.mean_direction + self.swing * np.sin(self.swing_frequency * tt + swing_phases)
        force = force_amplitudes * np.sin(w * tt + force_phases)
        moment = moment_amplitudes * np.sin(w * tt + moment_phases)
        b = np.empty(t.shape + (3,))
        b[..., 0] = np.sum(force * np.cos(beta), -1)
        b[..., 1] = np.sum(force * np.sin(beta), -1)
        b[..., 2] = np.sum(moment, -1)
        return b + current

    @classmethod
    def batched(cls, realizations: Sequence[EnvironmentDisturbance]) -> Callable[[float], np.ndarray] | None:
        """b(t) of K realizations at once, (K, 3) at a time t (s), each row bit for bit its
        realization's ``b(t)``: the same elementwise operations on their parameters stacked by row
        (a batch's runs, each with its own sea). None where their numbers of components differ."""
        fields = [r._arrays for r in realizations]
        if len({f[0].shape for f in fields}) != 1:
            return None
        w, swing_phases, force_amplitudes, force_phases, moment_amplitudes, moment_phases, current = (
            np.stack(column) for column in zip(*fields)
        )
        mean = np.array([[r.mean_direction] for r in realizations])
        swing = np.array([[r.swing] for r in realizations])
        swing_frequency = np.array([[r.swing_frequency] for r in realizations])

        def b(t: float) -> np.ndarray:
            beta = mean + swing * np.sin(swing_frequency * t + swing_phases)
            force = force_amplitudes * np.sin(w * t + force_phases)
            moment = moment_amplitudes * np.sin(w * t + moment_phases)
            found = np.empty((len(w), 3))
            found[:, 0] = np.sum(force * np.cos(beta), -1)
            found[:, 1] = np.sum(force * np.sin(beta), -1)
            found[:, 2] = np.sum(moment, -1)
            return found + current

        return b


def environment_disturbance(
    t: float | np.ndarray, rng_or_seed: int | np.random.SeedSequence | np.random.Generator, **magnitudes: Any
) -> np.ndarray:
    """b(t) of the realization ``EnvironmentDisturbance.random(rng_or_seed, **magnitudes)``; pure:
    the same seed (or Generator state) gives the same b at every t. Shape (3,) or (len(t), 3)."""
    return EnvironmentDisturbance.random(rng_or_seed, **magnitudes)(t)
