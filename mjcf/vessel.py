"""The over-actuated surface vessel of Cristofaro & Johansen, Sec. 4 (paper 003).

Ship model (Sec. 4):

    η̇ = P(ψ) ν,        M ν̇ = −V(η, ν) + τ + Pᵀ(ψ) b(t),        τ = G u,

η = [x, y, ψ] (earth frame), ν = [u, v, r] (surge, sway, yaw rate in the body frame), M the inertia
matrix including added mass, V the Coriolis and damping terms (damping −D ν), b(t) an earth-frame
disturbance with |b(t)| ≤ ε = 5e6. Linearized at a heading ψ̄ (eq. (23)):

    Ẋ = A X + B τ + E(t),   A = [[0, P(ψ̄)], [0, −M⁻¹D]],   B = [[0], [M⁻¹]],   C = I₆.

This module gives the paper's constants (``PAPER_M``, ``PAPER_D``, ``THRUSTERS``,
``thruster_matrix``, ``paper_model``, ``DISTURBANCE_BOUND``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

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
