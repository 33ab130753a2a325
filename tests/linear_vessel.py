"""The ship of Cristofaro & Johansen, Sec. 4, as the linear model (23) simulated in closed loop in
process (a test fixture, not a plant: the co-simulation uses mjcf/vessel.xml). Inputs are held
over each sample (as the runner's actuators hold them), so the discretization is exact."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from estimators import LinearModel
from estimators.design import zoh_discretize
from mjcf.vessel import INPUTS, PAPER_D, PAPER_M, disturbance_matrix, paper_model, thruster_matrix

A, B_TAU, W, C = paper_model()
G = thruster_matrix()
E = disturbance_matrix()
M, D = PAPER_M, PAPER_D
STATES = ("x", "y", "psi", "u", "v", "r")
X0 = np.array([1.0, 1.0, 0.0, 2.2, 1.9, 0.0])  # η0 = (1, 1, 0), ν0 = (2.2, 1.9, 0), Sec. 4
THRUSTER_OF_INPUT = np.array([0, 0, 1, 1, 2, 2, 3, 4])


def model() -> LinearModel:
    """The continuous model an estimator gets: (A, B = W, C = I₆, E = [0; M⁻¹]) of eq. (23)."""
    return LinearModel(A, W, C, np.zeros((6, 8)), None, STATES, INPUTS, STATES, E=E, disturbances=("bx", "by", "bn"))


def disturbance(epsilon: float, seed: int = 0) -> Callable[[float], np.ndarray]:
    """b(t) with |b(t)|₂ ≤ ε: a current of random fixed direction (0.6 ε) plus a wave force of
    slowly turning direction and a yaw moment (together at most 0.4 ε)."""
    rng = np.random.default_rng(seed)
    heading, phase = rng.uniform(0, 2 * np.pi, 2)
    current = 0.6 * epsilon * np.array([np.cos(heading), np.sin(heading), 0.0])

    def b(t: float) -> np.ndarray:
        direction = phase + 0.05 * t
        wave = np.array(
            [
                0.8 * np.cos(direction) * np.sin(0.6 * t),
                0.8 * np.sin(direction) * np.sin(0.6 * t),
                0.6 * np.cos(0.45 * t),
            ]
        )
        return current + 0.4 * epsilon * wave

    return b


def exponential_faults(rates: dict[int, float]) -> Callable[[float], np.ndarray]:
    """δ_j(t) = e^(−rate t) on thruster j (1-based) from t = 0, Δ = diag(δ1, δ1, δ2, δ2, δ3, δ3, δ4, δ5)."""

    def delta(t: float) -> np.ndarray:
        per_thruster = np.ones(5)
        for j, rate in rates.items():
            per_thruster[j - 1] = np.exp(-rate * t)
        return per_thruster[THRUSTER_OF_INPUT]

    return delta


@dataclass
class Trajectory:
    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    diagnostics: list[dict[str, float]]
    controls: list[dict[str, float]]

    def series(self, name: str) -> np.ndarray:
        return np.array([d[name] for d in self.diagnostics])

    def control(self, name: str) -> np.ndarray:
        return np.array([c[name] for c in self.controls])


def simulate(
    duration: float,
    tau: float,
    controller,
    estimator=None,
    delta=None,
    b=None,
    x0=X0,
    mask: Callable[[float], int] | None = None,
) -> Trajectory:
    """Closed loop: at t_k the controller gets y_k = x_k and the fault mask (the estimator's of
    tick k − 1, or ``mask(t)``), the estimator gets y_k and the command u_k; the plant holds
    Δ(t_k) u_k and b(t_k) over [t_k, t_k+1)."""
    Phi, Gamma = zoh_discretize(A, np.hstack([W, E]), tau)
    steps = round(duration / tau)
    x = np.asarray(x0, dtype=float).copy()
    report = 0
    ts, xs, us, diags, ctrls = [], [], [], [], []
    for k in range(steps):
        t = k * tau
        fault_mask = mask(t) if mask is not None else report
        u, control = controller.step(x.copy(), t, fault_mask)
        diag = estimator.step(x.copy(), u).diagnostics if estimator is not None else {}
        report = int(diag.get("fault_mask", 0))
        ts.append(t), xs.append(x.copy()), us.append(u), diags.append(diag), ctrls.append(control)
        u_eff = u if delta is None else delta(t) * u
        dist = np.zeros(3) if b is None else b(t)
        x = Phi @ x + Gamma @ np.concatenate([u_eff, dist])
    return Trajectory(np.array(ts), np.array(xs), np.array(us), diags, ctrls)
