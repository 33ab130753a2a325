"""Constrained output fault direction (COFD) unknown input observers: actuator fault detection and
isolation in over-actuated systems, with cluster residuals for common-mode faults.

Cristofaro & Johansen, "Fault-Tolerant Control Allocation: an Unknown Input Observer based
approach" (shared/papers/003), Sec. 3. The plant ẋ = A x + W Δ(t) u + E b, y = C x, with
W = B G (9) of rank k < m, multiplicative faults Δ = diag(δ_1, …, δ_m) and an unknown input b,
|b(t)|₂ ≤ ε. The observer

    ż = F z + R W u + K y,   x̂ = z + H y                                                  (Sec. 2)

with R = I − H C (6), F = R A − K1 C Hurwitz (7), K = K1 + K2, K2 = F H (8) has the error

    ė = F e + R W (Δ − I) u + R E b,   e = x − x̂.

COFD design (Sec. 3.2): S with C S = I (10); for a multi-index J of ℓ columns of W,
R W_J = Ŝ = [S_1 … S_ℓ] (13) through H of (15), and each S_j an eigenvector of F (14), so that a
fault on column J_j drives the residual r = C e along e_j. Faults on the other columns drive
combinations; a family of observers with different J isolates them (Theorem 3.1). Cluster
residuals (Sec. 3.3): with the inputs constrained to u_b = ζ u_a in each cluster (20), (24), the
cluster acts through the single column W_{j} = W N_j (22), (25) and the design is run on
W* = [W_{1} … W_{q}].

Plain functions: ``output_directions`` (10), ``uniform_subrank`` (12), ``cofd_observer`` (13)–(17)
with every condition of Theorem 3.1 checked, ``cofd_family``, ``cluster_directions`` (21)–(22),
``residual_bounds`` (the fault-free bound under |b| ≤ ε; estimators/thresholds.py has the bounds
for a declared environment), ``fault_signatures`` / ``isolate`` (the isolation logic).
``COFDDiagnosis`` is the estimator node (kind ``cofd``). docs/vessel-fdi.md has the derivations
and the choices the paper leaves open.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.integrate
import scipy.linalg

from estimators.allocation import FAULT_MASK, MAX_THRUSTERS, AllocationError, cluster_matrix, input_groups, whole
from estimators.base import Estimate, Estimator, ParameterError
from estimators.design import AssumptionError
from estimators.diagnostics import Diagnostic, DiagnosticKind
from estimators.isolation import isolate, unisolable
from estimators.model import LinearModel
from estimators.rotating_frame import FrameTerms
from estimators.thresholds import DeclaredEnvironment, centred_thresholds, check_declared, residual_test
from estimators.uio import UIODesign, discretize


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


# -- the diagnosis node ---------------------------------------------------------------------------

#: The paper's ship (Sec. 4): thrusters T1 … T5 as columns of W (1-based), the single-fault family
#: R^(h)[W_j …] = [e1 e2 e3], the cluster family (26) over W*, F, and the common-mode pairs of Table 1.
SHIP_GROUPS = ((1, 2), (3, 4), (5, 6), (7,), (8,))
SHIP_FAMILY = ((1, 2, 3), (3, 4, 1), (5, 6, 1), (7, 8, 1))
SHIP_CLUSTER_FAMILY = ((1, 2, 3), (1, 4, 5), (2, 3, 4), (2, 3, 5))
SHIP_F = (-1.0, -1.0, -2.0, -5.0, -6.0, -7.0)
SHIP_PAIRS = ((1, 3), (1, 4), (2, 3), (2, 5), (3, 4))
MAX_OBSERVERS, MAX_COMPONENTS = 4, 3
"""The residual components declared on the bus: r<h>_<i> for h ≤ 4, i ≤ 3 (and thrusters T1 … T5:
``estimators.allocation.MAX_THRUSTERS``, the bits of ``FAULT_MASK``)."""
COMPONENTS = tuple((h, i) for h in range(1, MAX_OBSERVERS + 1) for i in range(1, MAX_COMPONENTS + 1))
THRUSTERS = tuple(range(1, MAX_THRUSTERS + 1))

RESIDUAL = Diagnostic(
    "r{0}_{1}",
    "",
    "residual r^({0}) = C e^({0}) along e_{1} (Sec. 3.2), less its learned fault-free mean",
    1e9,
    1e-3,
    DiagnosticKind.RESIDUAL,
    "observer {0}",
)
THRESHOLD = Diagnostic(
    "thr{0}_{1}",
    "",
    "threshold of r{0}_{1}: margin × its fault-free bound (|b| ≤ ε, or the declared environment)",
    1e9,
    1e-3,
    DiagnosticKind.THRESHOLD,
    "r{0}_{1}",
)
ALARM = Diagnostic("alarm", "", "1 while some residual component exceeds its threshold", 1.0, 1.0, DiagnosticKind.ALARM)
ISOLATED = Diagnostic(
    "isolated_T{}", "", "1 once thruster T{} is isolated as faulty (latched)", 1.0, 1.0, DiagnosticKind.ISOLATION, "T{}"
)
CONSTRAINTS_MET = Diagnostic(
    "constraints_met",
    "",
    "1 when the commands obey the cluster constraints (24) (always 1 for the single-fault family)",
    1.0,
    1.0,
    DiagnosticKind.CONSTRAINT,
)


@dataclass(frozen=True)
class COFDParams(DeclaredEnvironment):
    groups: tuple[tuple[float, ...], ...] = SHIP_GROUPS
    """The inputs (1-based columns of B = W) of each thruster T1, T2, …; bit j − 1 of fault_mask is Tj."""
    family: tuple[tuple[float, ...], ...] | None = None
    """Multi-indices J_h: for each observer the columns (1-based, ordered) given directions e_1, e_2, …
    — columns of W, or with ``zeta`` thrusters (columns of W*). None: the paper's (Sec. 4, eq. (26))."""
    F: tuple[float, ...] = SHIP_F
    """Diagonal of the observer matrix F (n values, negative), the same for every observer (Sec. 4)."""
    zeta: tuple[float, ...] | None = None
    """Cluster ratios of eq. (24) (u_b = ζ u_a per thruster): run the cluster family (26) on W* instead."""
    pairs: tuple[tuple[float, ...], ...] | None = None
    """Double faults (thruster numbers) to consider besides single ones. None: none for the single
    family, the common-mode pairs of Table 1 for the cluster family."""
    E: tuple[tuple[float, ...], ...] | None = None
    """Direction of the unknown input b (n rows); None: the model's E."""
    disturbance_bound: float = 5e6
    """ε with |b(t)|₂ ≤ ε (the paper's 5·10⁶, Sec. 4), in the units of E's inputs."""
    margin: float = 1.2
    """Thresholds = margin × the fault-free bound of each residual component (≥ 1)."""
    persistence: float = 1.0
    """Seconds the same fault must be isolated, tick after tick, before it is reported (latched)."""
    x0: tuple[float, ...] | None = None
    """Initial estimate (absolute); None: C⁺ y(0), so e(0) = 0 when C is injective (C = I)."""
    rotating_frame: bool = False
    """The outputs are the vessel's (x, y, ψ, u, v, r): add the body frame's kinematic terms that the
    linearization at ψ = 0 drops (estimators/rotating_frame.py)."""
    thresholds: tuple[tuple[float, ...], ...] | None = None
    """The thresholds as designed, one row per observer: margin × the fault-free bounds (|b| ≤ ε) and,
    with a declared environment, margin × the centred bounds after them. None: computed (a few tenths
    of a second of numerical integration); the design cache and the runner pass them on."""


class COFDDiagnosis(Estimator):
    """Fault detection and isolation with a family of COFD observers (Sec. 3–4), integrated exactly
    between samples like ``uio`` (u held, y linear). Publishes x̂ = C⁺y (the measured state), the residual components
    r<h>_<i> = e_iᵀ r^(h) (less their means learned fault-free, with a declared environment:
    estimators/thresholds.py) and their thresholds thr<h>_<i>, ``alarm`` (some component above its
    threshold), ``isolated_T<j>`` and ``fault_mask`` (latched isolations) and, for the cluster
    family, ``constraints_met`` (the commands obey (24); isolation waits while they do not)."""

    kind = "cofd"
    Params = COFDParams
    continuous = True

    def __init__(self, model: LinearModel, params: COFDParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        self.groups = input_groups(params.groups, model.m)
        if len(self.groups) > MAX_THRUSTERS:
            raise ParameterError(
                "groups", f"at most {MAX_THRUSTERS} thrusters have diagnostics on the bus, got {len(self.groups)}"
            )
        _check_params(params, model.n)
        E = _disturbance_direction(model, params.E)
        cluster = params.zeta is not None
        family = _family(params, len(self.groups) if cluster else model.m)
        W, self.N = model.B, None
        try:
            if params.zeta is not None:  # the cluster family (26) on W* = W N
                W = cluster_directions(model.B, self.groups, params.zeta)
                self.N = cluster_matrix(self.groups, params.zeta, model.m)
            self.observers = cofd_family(model.A, W, model.C, family, np.diag(params.F))
        except DesignError as error:
            raise ParameterError(error.parameter, f"{error} (Cristofaro & Johansen, Sec. 3)") from None
        effect_groups = [(j,) for j in range(len(self.groups))] if cluster else self.groups
        self.signatures = fault_signatures(self.observers, model.C, W, effect_groups)
        self.hypotheses = self._isolable_hypotheses(
            params.pairs if params.pairs is not None else SHIP_PAIRS if cluster else ()
        )
        self.ell = max(len(J) for J in family)
        self.thresholds, centred = self._thresholds(E)
        self.test = residual_test(self.observers, model.C, E, params, self.thresholds, centred, self.sample_time)
        self.discrete = [discretize(o, model.B, self.sample_time) for o in self.observers]
        self.frame = FrameTerms(model, self.observers, self.sample_time) if params.rotating_frame else None
        self.x_init = None if params.x0 is None else np.asarray(params.x0, dtype=float) - model.x_op
        if self.x_init is not None and self.x_init.shape != (model.n,):
            raise ParameterError("x0", f"expected {model.n} values, got {self.x_init.size}")
        self._measured = np.linalg.pinv(model.C)
        self.z: list[np.ndarray] | None = None
        self.y_prev = np.zeros(model.p)
        self.u_prev = np.zeros(model.m)
        self.candidate: tuple[int, ...] | None = None
        self.candidate_since = 0.0
        self.t = 0.0
        self.isolated = np.zeros(len(self.groups), dtype=bool)

    def _thresholds(self, E: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """margin × the fault-free bounds of each observer's first ℓ components, and with a declared
        environment margin × their centred bounds (``residual_test``); as given, if they are."""
        params, C = self.params, self.model.C
        if params.declared:
            check_declared(params, E, self.sample_time)
        rows = len(self.observers) * (2 if params.declared else 1)
        if params.thresholds is not None:
            given = np.array(params.thresholds, dtype=float)
            if given.shape != (rows, self.ell):
                raise ParameterError("thresholds", f"expected {rows} rows of {self.ell} values, got {given.shape}")
            return given[: len(self.observers)], given[len(self.observers) :] if params.declared else None
        bounds = [residual_bounds(o, C, E, params.disturbance_bound)[: self.ell] for o in self.observers]
        flat = np.array([params.margin * bound for bound in bounds])
        return flat, centred_thresholds(self.observers, C, E, params, self.sample_time, self.ell)

    def node_params(self) -> dict[str, Any]:
        test = self.test.flat if self.test.centred is None else np.vstack([self.test.flat, self.test.centred])
        return {"thresholds": test.tolist()}

    def _isolable_hypotheses(self, pairs: Sequence[Sequence[Any]]) -> list[tuple[int, ...]]:
        """The single faults and the given double ones (thruster numbers), 0-based, each of which
        the family can tell from every other (Sec. 3.2)."""
        hypotheses = [(j,) for j in range(len(self.groups))] + [
            tuple(sorted(whole(t, "pairs") - 1 for t in pair)) for pair in pairs
        ]
        if any(not 0 <= t < len(self.groups) for H in hypotheses for t in H):
            raise ParameterError("pairs", f"thruster numbers run 1…{len(self.groups)}")
        clashes = unisolable(self.signatures, hypotheses)
        if clashes:
            H, other = clashes[0]
            raise ParameterError(
                "family" if self.params.zeta is None else "pairs",
                f"a fault on {_names(H)} cannot be isolated from one on {_names(other)}: every residual component "
                f"it moves can also be moved by {_names(other)} (isolation, Sec. 3.2). Choose multi-indices that "
                "separate them, drop the hypothesis from pairs, or use the cluster family (zeta) for common-mode "
                "faults",
            )
        return hypotheses

    @classmethod
    def diagnostic_channels(cls, states: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        return [
            *RESIDUAL.over(COMPONENTS),
            *THRESHOLD.over(COMPONENTS),
            ALARM,
            *ISOLATED.over(THRUSTERS),
            FAULT_MASK,
            CONSTRAINTS_MET,
        ]

    def _constraints_met(self, u: np.ndarray) -> bool:
        """u ∈ span N (eq. (24)) to 0.1 % of |u|∞: the commands arrive quantized over the bus."""
        if self.N is None:
            return True
        projection = self.N @ np.linalg.lstsq(self.N, u, rcond=None)[0]
        return bool(np.abs(u - projection).max() <= 1e-3 * max(np.abs(u).max(), 1e-9))

    @classmethod
    def batched(cls, instances: Sequence[Any]) -> Any:
        from estimators.cofd_batch import COFDBatch

        return COFDBatch(instances)

    def isolation_targets(self) -> dict[str, list[str]]:
        """isolated_T<j> names the inputs of thruster j (the columns of B in its group)."""
        return {ISOLATED.named(j + 1): [self.model.inputs[c] for c in group] for j, group in enumerate(self.groups)}

    def _step(self, dy: np.ndarray, du: np.ndarray) -> Estimate:
        model = self.model
        y = np.where(np.isnan(dy), self.y_prev, dy)
        if self.z is None:
            x0 = np.linalg.pinv(model.C) @ y if self.x_init is None else self.x_init
            self.z = [x0 - o.H @ y for o in self.observers]
        else:
            self.t += self.sample_time
            frame = self.frame(self.y_prev, y) if self.frame else [0.0] * len(self.z)
            self.z = [
                Phi @ z + Gu @ self.u_prev + Gy0 @ self.y_prev + Gy1 @ y + kinematics
                for z, (Phi, Gu, Gy0, Gy1), kinematics in zip(self.z, self.discrete, frame)
            ]
        x_hats = [z + o.H @ y for z, o in zip(self.z, self.observers)]
        residuals, thresholds = self.test(self.t, np.array([(y - model.C @ x)[: self.ell] for x in x_hats]), y)
        fired = np.abs(residuals) > thresholds
        constraints_met = self._constraints_met(self.u_prev + model.u_op)  # (24) constrains the absolute inputs
        found = isolate(fired, self.signatures, self.hypotheses) if constraints_met else None
        if found != self.candidate:
            self.candidate, self.candidate_since = found, self.t
        if found is not None and self.t - self.candidate_since >= self.params.persistence - 1e-9:
            self.isolated[list(found)] = True
        self.y_prev, self.u_prev = y, du
        shown = np.zeros((2, MAX_OBSERVERS, MAX_COMPONENTS))  # the components beyond the family's: 0
        shown[:, : len(self.observers), : self.ell] = residuals, thresholds
        isolated = np.zeros(MAX_THRUSTERS)
        isolated[: len(self.isolated)] = self.isolated
        diagnostics = RESIDUAL.values(COMPONENTS, shown[0].ravel()) | THRESHOLD.values(COMPONENTS, shown[1].ravel())
        diagnostics[ALARM.name] = float(fired.any())
        diagnostics |= ISOLATED.values(THRUSTERS, isolated)
        diagnostics[FAULT_MASK.name] = float(sum(1 << j for j in np.flatnonzero(self.isolated)))
        diagnostics[CONSTRAINTS_MET.name] = float(constraints_met)
        # The observers are residual generators: their states carry R-scaled fault and disturbance
        # effects (tens of metres for a 100 N current), so the state this node publishes is the
        # measured one, C⁺ y (C = I for the ship).
        return Estimate(self._measured @ y, diagnostics)


def _check_params(params: COFDParams, n: int) -> None:
    if len(params.F) != n or max(params.F) >= 0:
        raise ParameterError(
            "F", f"give the {n} diagonal entries of F, all negative (F Hurwitz, Theorem 3.1), got {list(params.F)}"
        )
    if params.margin < 1:
        raise ParameterError(
            "margin",
            f"must be at least 1 (a smaller one lets the worst-case disturbance raise alarms), got {params.margin}",
        )
    if not params.disturbance_bound >= 0 or params.persistence < 0:
        raise ParameterError(
            "disturbance_bound" if not params.disturbance_bound >= 0 else "persistence", "must be at least 0"
        )


def _disturbance_direction(model: LinearModel, given: tuple[tuple[float, ...], ...] | None) -> np.ndarray:
    """E of the unknown input b: the given one, or the model's."""
    E = model.E if given is None else np.array(given, dtype=float)
    if E.ndim != 2 or E.shape[0] != model.n or E.shape[1] == 0:
        raise ParameterError(
            "E", f"need the unknown input's direction, a matrix with {model.n} rows: the model has none, give params.E"
        )
    return E


def _family(params: COFDParams, columns: int) -> list[tuple[int, ...]]:
    """The multi-indices J_h, 0-based: the given ones or the paper's, each of columns of W (or,
    with ``zeta``, of W*, one per thruster)."""
    cluster = params.zeta is not None
    given = params.family or (SHIP_CLUSTER_FAMILY if cluster else SHIP_FAMILY)
    family = [tuple(whole(j, "family") - 1 for j in J) for J in given]
    if len(family) > MAX_OBSERVERS or any(len(J) > MAX_COMPONENTS for J in family):
        raise ParameterError(
            "family",
            f"at most {MAX_OBSERVERS} observers of at most {MAX_COMPONENTS} columns have diagnostics on the bus",
        )
    if any(not 0 <= j < columns for J in family for j in J):
        raise ParameterError(
            "family",
            f"multi-indices number the {'thrusters 1…' if cluster else 'inputs 1…'}{columns}, got "
            f"{[[j + 1 for j in J] for J in family]}",
        )
    return family


def _names(hypothesis: Sequence[int]) -> str:
    return " + ".join(f"T{j + 1}" for j in hypothesis)
