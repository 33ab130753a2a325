"""Theorem 2 of IJC 2018 (Behzad et al.): the LFT design of one constant UIO gain L = Q⁻¹ S
(Sec. 3.2.2, eq. (34)–(43)), with T_γ̂ and C̄_γ̂ as linear fractional transformations of the sensor
gains (eq. (60)–(61), normalized: docs/errata.md).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from estimators.lmi import (
    MARGIN,
    DesignError,
    SensorFaultModel,
    box_vertices,
    check_assumptions,
    check_certificate,
    solve_problem,
    solved_value,
)


@dataclass(frozen=True)
class SensorFaultLft:
    """The LFT form (34)–(35) of T_γ̂ and C̄_γ̂ for sensor gain faults (eq. (60)–(61)):

    T_γ̂ = T11 + T12 θ_T T21 and C̄_γ̂ = C11 + C12 θ_C C21 with θ_T = diag(δ_T), θ_C = diag(δ_C),
    |δ| ≤ 1, where 1/γ̂_j = a_j + b_j δ_T,j and γ̂_j = c_j + d_j δ_C,j (T22 = C22 = 0, so D_qp = 0).
    """

    T11: np.ndarray
    T12: np.ndarray
    T21: np.ndarray
    C11: np.ndarray
    C12: np.ndarray
    C21: np.ndarray


def sensor_fault_lft(model: SensorFaultModel, lower: np.ndarray, upper: np.ndarray) -> SensorFaultLft:
    """The LFT of eq. (60)–(61), normalized so that |θ| ≤ 1 holds on Γ = [lower, upper]:

    - T: 1/γ_j = a_j + b_j δ_j with a = (1/γ̲ + 1/γ̄)/2, b = (1/γ̲ − 1/γ̄)/2 (the paper's "standard
      normalization"; its constant part a goes into T11);
    - C̄: γ_j = c_j + d_j δ_j with c = (γ̲ + γ̄)/2, d = (γ̄ − γ̲)/2. The paper takes θ_C = Δ(γ)
      itself, which is valid (0 ≤ γ ≤ 1) but leaves C11 = [0 F], a nominal output that sees no
      plant state; with it the LMI (42) is infeasible on every box we tried, the centred form is
      what makes the S-procedure bite (docs/three-tank.md).
    """
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    if np.any(lower <= 0) or np.any(upper > 1) or np.any(lower >= upper):
        raise DesignError(f"Γ must satisfy 0 < γ̲ < γ̄ ≤ 1 (got γ̲ = {lower.tolist()}, γ̄ = {upper.tolist()})")
    n, q, m = model.n, model.q, model.m
    nx = n + q
    a, b = (1.0 / lower + 1.0 / upper) / 2.0, (1.0 / lower - 1.0 / upper) / 2.0
    c, d = (lower + upper) / 2.0, (upper - lower) / 2.0
    EG = model.Ebar @ np.linalg.pinv(model.G)  # Ē G⁺, shape (nx, m)
    Cy0 = np.hstack([model.C, np.zeros((m, q))])  # [C_y 0]
    ZF = np.hstack([np.zeros((m, n)), model.F])  # [0 F]
    return SensorFaultLft(
        T11=np.eye(nx) - EG @ Cy0 - EG @ (a[:, None] * ZF),
        T12=-EG * b[None, :],
        T21=ZF,
        C11=ZF + c[:, None] * Cy0,
        C12=np.diag(d),
        C21=Cy0,
    )


@dataclass(frozen=True)
class LftDesign:
    """Solution of Theorem 2: the constant gain L = Q⁻¹ S, the Lyapunov matrix Q and the S-procedure
    multipliers λ (one, or one per uncertainty channel)."""

    L: np.ndarray
    Q: np.ndarray
    lam: np.ndarray
    mu: float
    min_eigenvalue: float
    seconds: float

    @property
    def sigma(self) -> float:
        """σ = √μ*, eq. (43)."""
        return float(np.sqrt(self.mu))


def lft_uio_design(
    model: SensorFaultModel,
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    multiplier: str = "scalar",
    solver: str = "CLARABEL",
    margin: float = MARGIN,
) -> LftDesign:
    """Theorem 2: minimise μ subject to the LMI (42) in Q = Qᵀ ≻ 0, S, λ > 0:

        [[Q, Q T11 Ā − S C11, [Q T12, −S C12], Q F_e],
         [⋆, Q − I − λ C_qxᵀ C_qx, −λ C_qxᵀ D_qp, −λ C_qxᵀ F_w],
         [⋆, ⋆, λ (I − D_qpᵀ D_qp), −λ D_qpᵀ F_w],
         [⋆, ⋆, ⋆, μ I − λ F_wᵀ F_w]] ≻ 0,

    with C_qx = [T21 Ā; C21], D_qp = 0, F_e = [T11 F̄, I], F_w = [[T21 F̄, 0]; [0, 0]] (eq. (34),
    (37)–(38)); L = Q⁻¹ S. ``multiplier="scalar"`` is the theorem's S-procedure, which treats the
    uncertainty as one full block with ‖p̃‖ ≤ ‖q̃‖ (48); ``"diagonal"`` uses one λ_i per channel
    (λ I → Λ = diag(λ_i)), the S-procedure for the diagonal Θ (35) that the plant actually has:
    it contains the scalar case, so its μ* is never larger.
    """
    import cvxpy as cp

    if multiplier not in ("scalar", "diagonal"):
        raise ValueError(f"unknown multiplier {multiplier!r}; use 'scalar' or 'diagonal'")
    lft = sensor_fault_lft(model, lower, upper)
    check_assumptions(model, box_vertices(lower, upper))
    Abar, Fbar = model.Abar, model.Fbar
    nx, m, q = model.n + model.q, model.m, model.q
    Cqx = np.vstack([lft.T21 @ Abar, lft.C21])  # (2m, nx)
    Fe = np.hstack([lft.T11 @ Fbar, np.eye(nx)])  # (nx, q + nx)
    nw, npq = Fe.shape[1], 2 * m
    Fw = np.zeros((npq, nw))
    Fw[:m, :q] = lft.T21 @ Fbar
    start = time.perf_counter()
    Qv = cp.Variable((nx, nx), symmetric=True)
    S = cp.Variable((nx, m))
    mu = cp.Variable()
    lam = cp.Variable(1 if multiplier == "scalar" else npq)
    Lam = lam * np.eye(npq) if multiplier == "scalar" else cp.diag(lam)
    row1 = [Qv, Qv @ lft.T11 @ Abar - S @ lft.C11, cp.hstack([Qv @ lft.T12, -S @ lft.C12]), Qv @ Fe]
    M = cp.bmat(
        [
            row1,
            [row1[1].T, Qv - np.eye(nx) - Cqx.T @ Lam @ Cqx, np.zeros((nx, npq)), -Cqx.T @ Lam @ Fw],
            [row1[2].T, np.zeros((npq, nx)), Lam, np.zeros((npq, nw))],
            [row1[3].T, (-Cqx.T @ Lam @ Fw).T, np.zeros((nw, npq)), mu * np.eye(nw) - Fw.T @ Lam @ Fw],
        ]
    )
    size = 2 * nx + npq + nw
    problem = cp.Problem(cp.Minimize(mu), [M >> margin * np.eye(size), Qv >> margin * np.eye(nx), lam >= margin])
    solve_problem(problem, solver, "Theorem 2 (LFT-UIO)")
    seconds = time.perf_counter() - start
    min_eig = float(np.linalg.eigvalsh((M.value + M.value.T) / 2).min())
    check_certificate(min_eig, margin, "Theorem 2 (LFT-UIO)")
    Q_value, S_value, lam_value, mu_value = (solved_value(v.value, "Theorem 2 (LFT-UIO)") for v in (Qv, S, lam, mu))
    return LftDesign(
        np.linalg.solve(Q_value, S_value), Q_value, np.atleast_1d(lam_value), float(mu_value), min_eig, seconds
    )
