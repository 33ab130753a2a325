"""The design of constrained output fault direction (COFD) unknown input observers, Sec. 3 of
Cristofaro & Johansen, "Fault-Tolerant Control Allocation: an Unknown Input Observer based
approach" (shared/papers/003); ``estimators.cofd`` has the model, the diagnosis node and the
derivation's outline.

Plain functions: ``output_directions`` (10), ``uniform_subrank`` (12), ``cofd_observer`` (13)–(17)
with every condition of Theorem 3.1 checked, ``cofd_family``, ``cluster_directions`` (21)–(22),
``residual_bounds`` (the fault-free bound under |b| ≤ ε; estimators/thresholds.py has the bounds
for a declared environment), ``fault_signatures`` (which residual components a fault can move),
and the paper's ship (``SHIP_*``, Sec. 4).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.integrate
import scipy.linalg

from estimators.allocation import AllocationError, cluster_matrix
from estimators.design import AssumptionError
from estimators.uio import UIODesign


class DesignError(AssumptionError):
    """A design condition of Sec. 3 fails; ``parameter`` names what to change."""

    def __init__(self, parameter: str, message: str) -> None:
        super().__init__(message)
        self.parameter = parameter


def _tol(M: np.ndarray) -> float:
    """Relative: the vessel's W has entries of order 1/mass, 1e-7."""
    return 1e-9 * (float(np.abs(M).max()) if M.size else 0.0)


def _rank(M: np.ndarray) -> int:
    return int(np.linalg.matrix_rank(M, tol=_tol(M))) if M.size else 0


def _left_inverse(M: np.ndarray) -> np.ndarray:
    """(·)^{-L} = (MᵀM)⁻¹Mᵀ for M of full column rank."""
    return np.linalg.solve(M.T @ M, M.T)


def output_directions(C: np.ndarray, S_star: np.ndarray | None = None) -> np.ndarray:
    """S with C S = I_p, eq. (10): S = Cᵀ(CCᵀ)⁻¹ + [I − Cᵀ(CCᵀ)⁻¹C] S_* (S_* arbitrary, default 0).
    C (p, n) must have full row rank; returns (n, p)."""
    C = np.asarray(C, dtype=float)
    p, n = C.shape
    if _rank(C) < p:
        raise DesignError(
            "C", f"rank(C) = {_rank(C)} < p = {p}: no S with C S = I exists (eq. (10)); drop the redundant outputs"
        )
    right = C.T @ np.linalg.inv(C @ C.T)
    S_star = np.zeros((n, p)) if S_star is None else np.asarray(S_star, dtype=float)
    return right + (np.eye(n) - right @ C) @ S_star


def uniform_subrank(W: np.ndarray) -> int:
    """k0 of eq. (12): the largest ℓ ≤ rank W such that every ℓ columns of W are independent
    (0 if W has a zero column)."""
    W = np.asarray(W, dtype=float)
    k0 = 0
    for length in range(1, _rank(W) + 1):
        if all(_rank(W[:, list(J)]) == length for J in itertools.combinations(range(W.shape[1]), length)):
            k0 = length
        else:
            break
    return k0


@dataclass(frozen=True)
class COFDObserver(UIODesign):
    """One COFD unknown input observer O_h: ż = F z + R W u + K y, x̂ = z + H y, the UIO (2) with
    T = R (so ``estimators.uio.discretize`` integrates it)."""

    J: tuple[int, ...]
    """The columns of W (0-based, in order) assigned the output directions e_1 … e_ℓ, eq. (13)."""
    S_hat: np.ndarray
    """Ŝ = [S_1 … S_ℓ] (n, ℓ), eq. (13)."""

    @property
    def R(self) -> np.ndarray:
        """R = I − H C, eq. (6)."""
        return self.T


def cofd_observer(
    A: np.ndarray,
    W: np.ndarray,
    C: np.ndarray,
    J: Sequence[int],
    F: np.ndarray,
    S: np.ndarray | None = None,
    H_star: np.ndarray | None = None,
) -> COFDObserver:
    """The COFD observer with R W_J = Ŝ (13) and observer matrix F, eq. (15)–(17), (6)–(8).

    A (n, n), W (n, m), C (p, n), J: ℓ distinct columns of W (0-based, order = output direction),
    F (n, n) the wanted observer matrix, S from (10) (default Cᵀ(CCᵀ)⁻¹), H_* of (15) (default 0).

    1. Theorem 3.1, condition 1: rank(W_J) = rank(C W_J) = ℓ.
    2. H = (W_J − Ŝ)(C W_J)^{-L} + H_*(I_p − C W_J (C W_J)^{-L}) (15) (the paper prints C for I_p in
       the second bracket, see docs/errata.md), R = I − H C (6); then R W_J = Ŝ.
    3. Theorem 3.1, condition 2: F Hurwitz (7).
    4. Condition (14): each S_j (j ≤ ℓ) an eigenvector of F, F Ŝ = Ŝ M with M diagonal, as (16) needs.
    5. F = R A − K1 C must be solvable: K1 = (R A − F) C⁺, which then satisfies (16) and is of the
       form (17) (every solution of (16) is).
    6. K2 = F H (8).
    Raises DesignError naming the argument to change.
    """
    A, W, C, F = (np.asarray(X, dtype=float) for X in (A, W, C, F))
    n, p = A.shape[0], C.shape[0]
    J = tuple(int(j) for j in J)
    _check_shapes(A, W, C, F, J)
    S = output_directions(C) if S is None else np.asarray(S, dtype=float)
    if S.shape != (n, p) or not np.allclose(C @ S, np.eye(p), atol=1e-9):
        raise DesignError("S", "S must satisfy C S = I (eq. (10))")
    S_hat = S[:, : len(J)]
    H = _direction_gain(W[:, list(J)], C, S_hat, J, H_star)
    R = np.eye(n) - H @ C  # eq. (6)
    _check_observer_matrix(F, S_hat, J)
    K1 = _injection_gain(R @ A, C, F)
    return COFDObserver(H=H, T=R, F=F, K1=K1, K2=F @ H, J=J, S_hat=S_hat)


def _check_shapes(A: np.ndarray, W: np.ndarray, C: np.ndarray, F: np.ndarray, J: tuple[int, ...]) -> None:
    n, p = A.shape[0], C.shape[0]
    if A.shape != (n, n) or W.shape[0] != n or C.shape[1] != n:
        raise DesignError("model", f"inconsistent shapes A {A.shape}, W {W.shape}, C {C.shape}")
    if F.shape != (n, n):
        raise DesignError("F", f"expected an ({n}, {n}) observer matrix, got {F.shape}")
    if not J or len(set(J)) != len(J) or not all(0 <= j < W.shape[1] for j in J):
        raise DesignError("family", f"multi-index {[j + 1 for j in J]} must list distinct columns 1…{W.shape[1]} of W")
    if len(J) > p:
        raise DesignError(
            "family",
            f"multi-index {[j + 1 for j in J]} has {len(J)} columns but there are only p = {p} output directions",
        )


def _direction_gain(
    WJ: np.ndarray, C: np.ndarray, S_hat: np.ndarray, J: tuple[int, ...], H_star: np.ndarray | None
) -> np.ndarray:
    """H of eq. (15), which makes R W_J = Ŝ, after Theorem 3.1's condition 1."""
    ell, p = len(J), C.shape[0]
    CWJ = C @ WJ
    if _rank(WJ) != ell or _rank(CWJ) != ell:
        raise DesignError(
            "family",
            f"columns {[j + 1 for j in J]} of W: rank(W_J) = {_rank(WJ)}, rank(C W_J) = {_rank(CWJ)}, but Theorem "
            f"3.1 (condition 1) needs both = {ell}: these inputs' faults cannot be given independent output "
            "directions. Choose columns of W that are linearly independent (and stay so through C)",
        )
    CWJ_left = _left_inverse(CWJ)
    H = (WJ - S_hat) @ CWJ_left  # eq. (15)
    if H_star is not None:
        H = H + np.asarray(H_star, dtype=float) @ (np.eye(p) - CWJ @ CWJ_left)
    return H


def _check_observer_matrix(F: np.ndarray, S_hat: np.ndarray, J: tuple[int, ...]) -> None:
    """Theorem 3.1's condition 2 (F Hurwitz) and condition (14) (each S_j an eigenvector of F)."""
    eig = np.linalg.eigvals(F)
    if np.max(eig.real) >= 0:
        raise DesignError(
            "F",
            f"F has eigenvalues {np.round(eig, 6).tolist()}: Theorem 3.1 (condition 2) needs F Hurwitz, every real "
            "part negative",
        )
    for j in range(len(J)):
        s = S_hat[:, j]
        lam = s @ F @ s / (s @ s)
        if np.linalg.norm(F @ s - lam * s) > 1e-9 * max(1.0, np.abs(F).max()) * np.linalg.norm(s):
            raise DesignError(
                "F",
                f"S_{j + 1} is not an eigenvector of F: condition (14) fails, so a fault on input {J[j] + 1} would "
                f"not keep the output direction e_{j + 1}. Choose F with F S_j = λ_j S_j for j ≤ {len(J)} (with "
                f"C = I: F diagonal in its first {len(J)} rows and columns)",
            )


def _injection_gain(RA: np.ndarray, C: np.ndarray, F: np.ndarray) -> np.ndarray:
    """K1 = (R A − F) C⁺, the solution of F = R A − K1 C (7) when there is one; it is then of the
    form (17)."""
    K1 = (RA - F) @ (C.T @ np.linalg.inv(C @ C.T))
    if not np.allclose(RA - K1 @ C, F, atol=1e-9 * max(1.0, np.abs(RA).max(), np.abs(F).max())):
        raise DesignError(
            "F",
            "F = R A − K1 C (eq. (7)) has no solution K1: R A − F must vanish on the kernel of C. "
            "Choose F from the reachable ones, R A − K1 C for some K1 (eq. (17))",
        )
    return K1


def cofd_family(
    A: np.ndarray,
    W: np.ndarray,
    C: np.ndarray,
    family: Sequence[Sequence[int]],
    F: np.ndarray,
    S: np.ndarray | None = None,
) -> list[COFDObserver]:
    """The observers {O_h} of eq. (13), one per multi-index of ``family`` (0-based columns of W),
    all with the same F and Ŝ (the paper's simplification after (13)). DesignError names the observer."""
    observers = []
    for h, J in enumerate(family, 1):
        try:
            observers.append(cofd_observer(A, W, C, J, F, S))
        except DesignError as error:
            raise DesignError(error.parameter, f"observer {h}: {error}") from None
    return observers


def cluster_directions(W: np.ndarray, groups: Sequence[Sequence[int]], zeta: Sequence[float]) -> np.ndarray:
    """W* = [W_{1} … W_{q}] = W N (n, q), eq. (22), (25): the input direction of each cluster of
    inputs under the constraints u_b = ζ u_a (20), (24) (``estimators.allocation.cluster_matrix``).

    Checks eq. (19) generalized to q clusters (at most m − k constraints, so that τ = G u can still
    be met) and eq. (21) (rank W* = rank W, so every effect stays reachable); DesignError("zeta")."""
    W = np.asarray(W, dtype=float)
    try:
        N = cluster_matrix(groups, zeta, W.shape[1])
    except AllocationError as error:
        raise DesignError("zeta", str(error)) from None
    k, m = _rank(W), W.shape[1]
    constraints = m - N.shape[1]
    if constraints > m - k:
        raise DesignError(
            "zeta",
            f"{constraints} cluster constraints exceed the redundancy m − k = {m - k} (eq. (19)): merge fewer inputs",
        )
    W_star = W @ N
    if _rank(W_star) < k:
        raise DesignError(
            "zeta",
            f"rank [W_{{1}} … W_{{q}}] = {_rank(W_star)} < rank W = {k} (eq. (21)): with these ratios ζ some effect "
            "can no longer be produced; choose other ratios",
        )
    return W_star


def residual_bounds(observer: COFDObserver, C: np.ndarray, E: np.ndarray, epsilon: float) -> np.ndarray:
    """The least upper bound on |r_i(t)| = |(C e(t))_i| without faults, for every unknown input with
    |b(t)|₂ ≤ ε and e(0) = 0 (p values):

        sup |r_i| = ε ∫₀^∞ |c_iᵀ e^{F s} R E|₂ ds

    (the error is e(t) = ∫ e^{F s} R E b(t − s) ds; the bound is reached by the constant b along
    the integrand's direction when that direction is constant). For C = I and diagonal F it is
    ε |row_i(R E)|₂ / |f_i|. Integrated numerically up to where e^{F s} has decayed by e^(−40)."""
    C, E = np.asarray(C, dtype=float), np.asarray(E, dtype=float)
    F, RE = observer.F, observer.R @ E
    if E.shape[1] == 0:
        return np.zeros(C.shape[0])
    decay = -np.max(np.linalg.eigvals(F).real)
    horizon = 40.0 / decay

    def integrand(s: float) -> np.ndarray:
        return np.linalg.norm(C @ scipy.linalg.expm(F * s) @ RE, axis=1)

    value, _ = scipy.integrate.quad_vec(integrand, 0.0, horizon, epsrel=1e-10, epsabs=0.0)
    return epsilon * value


def fault_signatures(
    observers: list[COFDObserver], C: np.ndarray, W: np.ndarray, groups: Sequence[Sequence[int]]
) -> np.ndarray:
    """Which residual components a fault can move: s[h, i, j] is True when a fault of group j
    (a thruster: columns ``groups[j]`` of W) enters component i < ℓ of r^(h) = C e^(h), i.e. row i of
    C R^(h) W_{group j} is not zero; shape (observers, ℓ, groups). A False entry is a structural
    zero: that fault never moves that component (the paper's "negligible projection")."""
    C, W = np.asarray(C, dtype=float), np.asarray(W, dtype=float)
    ell = max(len(o.J) for o in observers)
    signatures = np.zeros((len(observers), ell, len(groups)), dtype=bool)
    for h, o in enumerate(observers):
        effect = C @ o.R @ W
        tol = _tol(effect)
        for j, g in enumerate(groups):
            signatures[h, : len(o.J), j] = np.abs(effect[: len(o.J), list(g)]).max(axis=1) > tol
    return signatures


#: The paper's ship (Sec. 4): thrusters T1 … T5 as columns of W (1-based), the single-fault family
#: R^(h)[W_j …] = [e1 e2 e3], the cluster family (26) over W*, F, and the common-mode pairs of Table 1.
SHIP_GROUPS = ((1, 2), (3, 4), (5, 6), (7,), (8,))
SHIP_FAMILY = ((1, 2, 3), (3, 4, 1), (5, 6, 1), (7, 8, 1))
SHIP_CLUSTER_FAMILY = ((1, 2, 3), (1, 4, 5), (2, 3, 4), (2, 3, 5))
SHIP_F = (-1.0, -1.0, -2.0, -5.0, -6.0, -7.0)
SHIP_PAIRS = ((1, 3), (1, 4), (2, 3), (2, 5), (3, 4))
