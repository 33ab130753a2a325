"""Control allocation for over-actuated systems and the vessel controller that uses it.

Cristofaro & Johansen, "Fault-Tolerant Control Allocation: an Unknown Input Observer based
approach" (shared/papers/003), Sec. 2 and 4. The generalized effect τ ∈ R^k is produced by
m > k inputs, τ = G u (rk G = k). Allocations, all plain functions on arrays:

- ``pseudo_inverse_allocation``: u = G⁻ᴿ τ, G⁻ᴿ = Gᵀ(GGᵀ)⁻¹                                      (4)
- ``reduced_allocation``: faulty inputs set to 0, the others ũ = G̃⁻ᴿ τ                          (5)
- ``constrained_allocation``: the common-mode constraints u_b = ζ u_a within each cluster of
  inputs (20), (24), with τ = G u still met exactly (needs rk(G N) = k, eq. (21))
- ``bounded_allocation``: lower ≤ u ≤ upper, G u = τ exactly when the limits allow it, otherwise
  the closest reachable τ̂ = G u ≠ τ (eq. (3)); weighted least squares (Härkegård), solved with
  bounded-variable least squares.

All of them are one computation on an allocation basis N (m × r, orthonormal columns with disjoint
supports) whose span holds the admissible inputs: u = N v. N = I gives (4); I without the columns
of faulty inputs gives (5); one column per cluster, e_a + Σ ζ e_b normalized, gives (24).
Minimizing |v| is minimizing |u| since NᵀN = I.

``VesselController`` is the paper's nominal law for the ship of Sec. 4 with this allocation.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.optimize
from numpy.typing import ArrayLike

from estimators.base import ParameterError
from estimators.controller import Command, Controller
from estimators.diagnostics import Diagnostic, DiagnosticKind
from estimators.lmi import pseudo_inverse
from estimators.model import LinearModel


class AllocationError(ValueError):
    """An allocation problem has no solution as posed (the message says what fails and what to change)."""


def _rank(M: np.ndarray) -> int:
    return int(np.linalg.matrix_rank(M, tol=1e-9 * float(np.abs(M).max()))) if M.size else 0


def _check_effect_matrix(G: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    G = np.asarray(G, dtype=float)
    tau = np.asarray(tau, dtype=float)
    if G.ndim != 2 or tau.shape != (G.shape[0],):
        raise AllocationError(f"expected G of shape (k, m) and τ of shape (k,), got {G.shape} and {tau.shape}")
    return G, tau


def pseudo_inverse_allocation(G: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """u = Gᵀ(GGᵀ)⁻¹ τ, eq. (4): the least-norm u with G u = τ. G (k, m) of rank k; returns (m,)."""
    G, tau = _check_effect_matrix(G, tau)
    if _rank(G) < G.shape[0]:
        raise AllocationError(
            f"rank(G) = {_rank(G)} < k = {G.shape[0]}: some direction of τ cannot be produced by any u (eq. (4) needs "
            "G of full row rank)"
        )
    return G.T @ np.linalg.solve(G @ G.T, tau)


def reduced_allocation(G: np.ndarray, tau: np.ndarray, faulty: tuple[int, ...] | list[int]) -> np.ndarray:
    """Reconfiguration by the reduced pseudo-inverse, eq. (5): u_i = 0 for the faulty inputs i
    (0-based columns of G) and ũ = G̃ᵀ(G̃G̃ᵀ)⁻¹ τ for the others, G̃ = G without those columns.
    Needs rank(G̃) = k (at most m − k faulty inputs, and the right ones); returns (m,)."""
    G, tau = _check_effect_matrix(G, tau)
    return allocate(G, tau, allocation_basis(G.shape[1], faulty=faulty), exact=True)


def cluster_matrix(groups: Sequence[Sequence[int]], zeta: Sequence[float], m: int) -> np.ndarray:
    """The input combinations N (m, q) of the common-mode constraints (20), (24): u = N v.

    ``groups`` partitions the inputs 0 … m−1 into q clusters (e.g. the ship's thrusters
    ((0, 1), (2, 3), (4, 5), (6,), (7,))). In a cluster (a, b, c, …) the constraints are
    u_b = ζ u_a, u_c = ζ′ u_a, …, taking the cluster's α − 1 ratios from ``zeta`` in order (the
    ship: ζ^(i) = u_{2i}/u_{2i−1}, eq. (24)); column j of N is e_a + ζ e_b + ζ′ e_c + …, so that the
    cluster's effect is v_j W N_j = v_j W_{j} of eq. (22) (see docs/errata.md on eq. (25)).
    """
    groups = [tuple(int(i) for i in g) for g in groups]
    flat = [i for g in groups for i in g]
    if any(len(g) == 0 for g in groups) or sorted(flat) != list(range(m)):
        raise AllocationError(
            f"groups {[list(g) for g in groups]} must split the inputs 0…{m - 1} into non-empty clusters, each input "
            "in exactly one"
        )
    needed = sum(len(g) - 1 for g in groups)
    zeta = [float(z) for z in zeta]
    if len(zeta) != needed:
        raise AllocationError(
            f"zeta has {len(zeta)} ratios; the clusters {[list(g) for g in groups]} need {needed} (one per input "
            "after the first of each cluster)"
        )
    if not all(np.isfinite(zeta)):
        raise AllocationError(f"zeta {zeta} must be finite")
    N = np.zeros((m, len(groups)))
    ratios = iter(zeta)
    for j, g in enumerate(groups):
        N[g[0], j] = 1.0
        for i in g[1:]:
            N[i, j] = next(ratios)
    return N


def cluster_ratios(u: np.ndarray, groups: list[tuple[int, ...]] | tuple[tuple[int, ...], ...]) -> np.ndarray:
    """The ratios ζ that the inputs u already satisfy in each cluster (u_b / u_a, …), the paper's
    choice ζ^(i) = u_{2i}(0)/u_{2i−1}(0) from the nominal allocation (Sec. 4)."""
    u = np.asarray(u, dtype=float)
    zeta = []
    for g in groups:
        g = tuple(int(i) for i in g)
        if len(g) > 1 and abs(u[g[0]]) <= 1e-12 * max(1.0, float(np.abs(u).max())):
            raise AllocationError(f"u[{g[0]}] = 0: the cluster {list(g)} has no ratio u_b/u_a; give zeta explicitly")
        zeta += [u[i] / u[g[0]] for i in g[1:]]
    return np.array(zeta)


def allocation_basis(
    m: int,
    groups: Sequence[Sequence[int]] | None = None,
    zeta: Sequence[float] | None = None,
    faulty: tuple[int, ...] | list[int] = (),
) -> np.ndarray:
    """The admissible inputs u = N v as an orthonormal basis N (m, r) with disjoint column supports:
    the unit vectors of the healthy inputs, or, with ``groups`` and ``zeta``, the normalized
    cluster combinations of ``cluster_matrix`` for the clusters without a faulty input."""
    failed = {int(i) for i in faulty}
    if any(not 0 <= i < m for i in failed):
        raise AllocationError(f"faulty inputs {sorted(failed)} must be columns 0…{m - 1} of G")
    if zeta is None:
        return np.eye(m)[:, [i for i in range(m) if i not in failed]]
    if groups is None:
        raise AllocationError("zeta needs the groups of inputs it relates")
    N = cluster_matrix(groups, zeta, m)
    keep = [j for j in range(N.shape[1]) if not any(N[i, j] != 0 for i in failed)]
    N = N[:, keep]
    return N / np.linalg.norm(N, axis=0)


def allocate(G: np.ndarray, tau: np.ndarray, N: np.ndarray | None = None, exact: bool = False) -> np.ndarray:
    """u = N (G N)⁺ τ: the least-norm u in span N with G u = τ, or with G u the least-squares τ̂
    when rank(G N) < k (then ``exact`` raises AllocationError instead). Returns (m,)."""
    G, tau = _check_effect_matrix(G, tau)
    N = np.eye(G.shape[1]) if N is None else np.asarray(N, dtype=float)
    GN = G @ N
    if exact and (N.shape[1] == 0 or _rank(GN) < G.shape[0]):
        raise AllocationError(
            f"the admissible inputs produce only a rank-{_rank(GN) if N.shape[1] else 0} effect (k = {G.shape[0]}): τ "
            "cannot be met "
            "exactly (eq. (5) and (21) need rank k); keep more inputs, or relax the cluster constraints"
        )
    # pseudo_inverse: np.linalg.pinv's numbers without its checks (the vessel allocates every tick)
    return N @ (pseudo_inverse(GN) @ tau) if N.shape[1] else np.zeros(G.shape[1])


def constrained_allocation(
    G: np.ndarray, tau: np.ndarray, groups: Sequence[Sequence[int]], zeta: Sequence[float]
) -> np.ndarray:
    """u meeting τ = G u exactly under the cluster constraints (24) (u_b = ζ u_a in every cluster),
    least-norm among those. Needs at most m − k constraints (eq. (19)) and rank(G N) = k (eq. (21))."""
    G, tau = _check_effect_matrix(G, tau)
    m, k = G.shape[1], G.shape[0]
    constraints = sum(len(g) - 1 for g in groups)
    if constraints > m - k:
        raise AllocationError(
            f"{constraints} cluster constraints leave {m - constraints} free inputs for k = {k} effects: eq. (19) "
            f"allows at most m − k = {m - k}"
        )
    return allocate(G, tau, allocation_basis(m, groups, zeta), exact=True)


def bounded_allocation(
    G: np.ndarray, tau: np.ndarray, lower: ArrayLike, upper: ArrayLike, N: np.ndarray | None = None, gamma: float = 1e6
) -> np.ndarray:
    """u in span N with lower ≤ u ≤ upper that meets G u = τ when the limits allow, least-norm
    among those; otherwise the τ̂ = G u closest to τ (eq. (3)).

    Weighted least squares (Härkegård 2004): min |v|² + γ |G N v − τ|² / s² over the box that
    the limits give v (N has orthonormal columns with disjoint supports, so each v_j is bounded by
    the limits of its cluster), s = |G N|₂ making γ unit-free; solved exactly by bounded-variable
    least squares. The WLS optimum misses G u = τ by O(1/γ); it is then polished: with the inputs
    at their limits fixed, the free ones are set to the least-norm exact solution, kept if it
    respects the limits (the KKT point of min |u|² s.t. G u = τ and the same active limits).
    Returns (m,).
    """
    G, tau = _check_effect_matrix(G, tau)
    m = G.shape[1]
    N = np.eye(m) if N is None else np.asarray(N, dtype=float)
    lower = np.broadcast_to(np.asarray(lower, dtype=float), (m,))
    upper = np.broadcast_to(np.asarray(upper, dtype=float), (m,))
    if np.any(lower > upper):
        raise AllocationError("every lower limit must be at most its upper limit")
    lo, hi = np.full(N.shape[1], -np.inf), np.full(N.shape[1], np.inf)
    for j in range(N.shape[1]):
        for i in np.flatnonzero(N[:, j]):
            a, b = lower[i] / N[i, j], upper[i] / N[i, j]
            lo[j], hi[j] = max(lo[j], min(a, b)), min(hi[j], max(a, b))
    if np.any(lo > hi):
        raise AllocationError(
            "the limits leave no admissible input in some cluster (its ratios ζ force an input beyond its limit)"
        )
    if N.shape[1] == 0:
        return np.zeros(m)
    GN = G @ N
    weight = np.sqrt(gamma) / max(np.linalg.norm(GN, 2), 1e-300)
    stacked = np.vstack([weight * GN, np.eye(N.shape[1])])
    target = np.concatenate([weight * tau, np.zeros(N.shape[1])])
    bounded = np.isfinite(lo) | np.isfinite(hi)
    v = scipy.optimize.lsq_linear(stacked, target, bounds=(lo, hi), method="bvls" if bounded.any() else "trf").x
    slack = 1e-9 * max(1.0, float(np.abs(v).max()))
    free = (v > lo + slack) & (v < hi - slack)
    if free.any() and _rank(GN[:, free]) == G.shape[0]:
        polished = v.copy()
        polished[free] = np.linalg.pinv(GN[:, free]) @ (tau - GN[:, ~free] @ v[~free])
        if np.all(polished >= lo - slack) and np.all(polished <= hi + slack):
            v = np.clip(polished, lo, hi)
    return N @ v


# -- the paper's controller for the ship of Sec. 4 ------------------------------------------------


@dataclass(frozen=True)
class VesselControllerParams:
    heading: float | None = None
    """Heading set point ψ_ref (rad); None: the heading measured at the first step."""
    heading_bandwidth: float = 0.1
    """ω_ψ (rad/s): the PID puts the yaw loop's three poles at −ω_ψ."""
    speed: tuple[float, ...] | None = None
    """(surge, sway) velocities (m/s) tracked after reconfiguration; None: ν measured at the first step."""
    speed_bandwidth: float = 0.1
    """ω_v (rad/s): after reconfiguration, the PI velocity loops put their two poles at −ω_v."""
    reconfigure_at: float = 180.0
    """t0 (s): no reconfiguration before this time (the paper's t0 = 180 s, Sec. 4)."""
    reconfigure_delay: float = 0.0
    """Least time (s) between a fault report and the reconfiguration it triggers."""
    groups: tuple[tuple[float, ...], ...] = ((1, 2), (3, 4), (5, 6), (7,), (8,))
    """The inputs (1-based columns of G) of each thruster; thruster j is bit j − 1 of the fault mask."""
    zeta: tuple[float, ...] | None = None
    """Cluster ratios of eq. (24) (u_b = ζ u_a per thruster); given: constrained allocation until reconfiguration."""
    thrust_limit: tuple[float, ...] | None = None
    """|u_i| ≤ limit (N), one per input or one for all: bounded allocation. None: unbounded pseudo-inverse."""


def _wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


MAX_THRUSTERS = 5
"""Thrusters a fault report names: the bits of ``FAULT_MASK``."""
FAULT_MASK = Diagnostic(
    "fault_mask",
    "",
    "isolated thrusters, bit j − 1 for Tj (latched)",
    2.0**MAX_THRUSTERS,
    1.0,
    DiagnosticKind.FAULT_MASK,
)
"""The report the thrust allocation reads from its diagnosis node (``cofd`` publishes it)."""

#: What ``VesselController.step`` reports each tick, in this order.
VESSEL_DIAGNOSTICS = (
    Diagnostic("tau_x", "N", "commanded surge force τ_c", 1e8, 1.0, DiagnosticKind.EFFORT),
    Diagnostic("tau_y", "N", "commanded sway force τ_c", 1e8, 1.0, DiagnosticKind.EFFORT),
    Diagnostic("tau_n", "N m", "commanded yaw moment τ_c", 1e10, 1.0, DiagnosticKind.EFFORT),
    Diagnostic("a_psi", "N m", "heading PID output a_ψ", 1e10, 1.0, DiagnosticKind.EFFORT),
    Diagnostic("heading_error", "rad", "ψ − ψ_ref", 4.0, 1e-6, DiagnosticKind.CONTROL_ERROR),
    Diagnostic("tau_error", "N", "|G u − τ_c| (unmet effect)", 1e8, 1.0, DiagnosticKind.CONTROL_ERROR),
    Diagnostic("cluster", "", "1 while the cluster constraints (24) hold", 1.0, 1.0, DiagnosticKind.CONSTRAINT),
    Diagnostic(
        "reconfigured", "", "1 once the allocation left thrusters out (5)", 1.0, 1.0, DiagnosticKind.RECONFIGURATION
    ),
    Diagnostic(
        "active_mask", "", "thrusters left out of the allocation (bit j: T(j+1))", 255.0, 1.0, DiagnosticKind.FAULT_MASK
    ),
)


class VesselController:
    """The nominal law of Sec. 4 with fault-tolerant allocation, in discrete time.

    Commanded effect, with y = [x, y, ψ, u, v, r] (C = I₆):

        τ_c = D ν + [0, 0, a_ψ]ᵀ                                         (constant speed, Sec. 4)
        a_ψ = −(3ω_ψ² e_ψ + ω_ψ³ ∫e_ψ + 3ω_ψ r) / (M⁻¹)₃₃,   e_ψ = ψ − ψ_ref (wrapped)

    The D ν term cancels the damping of (23), so M ν̇ = [0, 0, a_ψ]ᵀ + b: surge and sway keep their
    speed, and the yaw rate obeys ṙ = (M⁻¹)₃₃ a_ψ (the sway–yaw coupling of M included), so the PID
    (derivative on the measured r) places the heading loop at (s + ω_ψ)³. Gains: kp = 3ω_ψ²/(M⁻¹)₃₃,
    ki = ω_ψ³/(M⁻¹)₃₃, kd = 3ω_ψ/(M⁻¹)₃₃ (attributes ``kp``, ``ki``, ``kd``).

    Allocation: u = G⁺ τ_c (4); with ``zeta``, the cluster constraints (24) until reconfiguration;
    with ``thrust_limit``, the bounded allocation. Reconfiguration: once ``fault_mask`` reports
    thrusters, at the first step with t ≥ max(t0, t_report + delay) the allocation drops their
    inputs (5), the cluster constraints are lifted, and velocity feedback is added so that "the
    commanded control effect is modified in order to track the original vessel velocities in surge
    and sway" (Sec. 4):

        τ_c += M [a_u, a_v, 0]ᵀ,  a = 2ω_v (ν_ref − ν)_{u,v} + ω_v² ∫(ν_ref − ν)_{u,v}

    which makes ν̇_{u,v} = a + … : two poles at −ω_v, no steady error under a constant current.
    Reports only add thrusters (a reconfigured thruster is never taken back). The integrals stop
    while the allocation cannot meet τ_c (thrust limits, or too few thrusters left): anti-windup.
    """

    def __init__(
        self,
        M: np.ndarray,
        D: np.ndarray,
        G: np.ndarray,
        sample_time: float,
        params: VesselControllerParams = VesselControllerParams(),
    ) -> None:
        self.M, self.D, self.G = (np.asarray(X, dtype=float) for X in (M, D, G))
        if self.M.shape != (3, 3) or self.D.shape != (3, 3) or self.G.ndim != 2 or self.G.shape[0] != 3:
            raise ParameterError(
                "model",
                f"expected M and D of shape (3, 3) and G of shape (3, m), got {self.M.shape}, {self.D.shape}, "
                f"{self.G.shape}",
            )
        if not sample_time > 0:
            raise ParameterError("sample_time", f"must be positive, got {sample_time}")
        m = self.G.shape[1]
        self.params, self.sample_time, self.m = params, float(sample_time), m
        self.groups = input_groups(params.groups, m)
        for name in ("heading_bandwidth", "speed_bandwidth"):
            if not getattr(params, name) > 0:
                raise ParameterError(name, f"must be positive, got {getattr(params, name)}")
        if params.speed is not None and len(params.speed) != 2:
            raise ParameterError("speed", f"give (surge, sway) in m/s, got {len(params.speed)} values")
        if params.reconfigure_delay < 0:
            raise ParameterError("reconfigure_delay", "must be at least 0")
        self.limits = None
        if params.thrust_limit is not None:
            if len(params.thrust_limit) not in (1, m) or min(params.thrust_limit) <= 0:
                raise ParameterError("thrust_limit", f"give one positive limit per input ({m}) or one for all")
            self.limits = np.broadcast_to(np.asarray(params.thrust_limit, dtype=float), (m,)).copy()
        try:
            self.cluster_basis = None if params.zeta is None else allocation_basis(m, self.groups, params.zeta)
            if params.zeta is not None:
                constrained_allocation(self.G, np.zeros(3), self.groups, params.zeta)  # eq. (19), (21)
            pseudo_inverse_allocation(self.G, np.zeros(3))
        except AllocationError as error:
            raise ParameterError("zeta" if params.zeta is not None else "G", str(error)) from None
        gain = 1.0 / np.linalg.inv(self.M)[2, 2]
        w = params.heading_bandwidth
        self.kp, self.ki, self.kd = 3 * w**2 * gain, w**3 * gain, 3 * w * gain
        self.heading_ref: float | None = params.heading
        self.speed_ref: np.ndarray | None = None if params.speed is None else np.asarray(params.speed, dtype=float)
        self.heading_integral = 0.0
        self.speed_integral = np.zeros(2)
        self.reported, self.report_time = 0, 0.0
        self.active_mask = 0
        self.y_last = np.zeros(6)

    def step(self, y: np.ndarray, t: float, fault_mask: int = 0) -> tuple[np.ndarray, dict[str, float]]:
        """u_k (shape (m,)) from y_k = [x, y, ψ, u, v, r] (NaN: a reading that did not arrive, the
        last one is used), the time t_k and the latest fault report (bit j: thruster j + 1)."""
        y = np.asarray(y, dtype=float)
        if y.shape != (6,):
            raise ValueError(f"expected y = [x, y, psi, u, v, r], got shape {y.shape}")
        y = np.where(np.isfinite(y), y, self.y_last)
        self.y_last = y
        psi, nu = y[2], y[3:]
        if self.heading_ref is None:
            self.heading_ref = float(psi)
        if self.speed_ref is None:
            self.speed_ref = nu[:2].copy()
        fault_mask = int(fault_mask)
        if fault_mask & ~self.reported:
            self.reported |= fault_mask
            self.report_time = float(t)
        if self.reported & ~self.active_mask and t >= max(
            self.params.reconfigure_at, self.report_time + self.params.reconfigure_delay
        ):
            self.active_mask |= self.reported

        error = _wrap(psi - self.heading_ref)
        heading_integral = self.heading_integral + self.sample_time * error
        a_psi = -(self.kp * error + self.ki * heading_integral + self.kd * nu[2])
        tau = self.D @ nu + np.array([0.0, 0.0, a_psi])
        speed_integral = self.speed_integral
        if self.active_mask:
            speed_error = self.speed_ref - nu[:2]
            speed_integral = self.speed_integral + self.sample_time * speed_error
            w = self.params.speed_bandwidth
            tau += self.M[:, :2] @ (2 * w * speed_error + w**2 * speed_integral)

        faulty = [i for j, g in enumerate(self.groups) if self.active_mask >> j & 1 for i in g]
        clustered = self.cluster_basis is not None and not self.active_mask
        N = self.cluster_basis if clustered else allocation_basis(self.m, faulty=faulty)
        if self.limits is None:
            u = allocate(self.G, tau, N)
        else:
            u = bounded_allocation(self.G, tau, -self.limits, self.limits, N)
        tau_error = float(np.linalg.norm(self.G @ u - tau))
        if tau_error <= 1e-6 * np.linalg.norm(tau):  # anti-windup: integrate only while τ_c is met
            self.heading_integral, self.speed_integral = heading_integral, speed_integral
        values = (*tau, a_psi, error, tau_error, clustered, self.active_mask != 0, self.active_mask)
        return u, {d.name: float(value) for d, value in zip(VESSEL_DIAGNOSTICS, values)}


def input_groups(groups: Sequence[Sequence[Any]], m: int, parameter: str = "groups") -> list[tuple[int, ...]]:
    """1-based input numbers per thruster (as parsed from TOML) → 0-based column tuples, checked to
    split the m inputs, each in exactly one thruster; ParameterError(``parameter``) otherwise."""
    out = [tuple(whole(i, parameter) - 1 for i in g) for g in groups]
    if not out or any(not g for g in out) or sorted(i for g in out for i in g) != list(range(m)):
        raise ParameterError(
            parameter,
            f"{[[int(i) for i in g] for g in groups]} must split the inputs 1…{m} into thrusters, each input in "
            "exactly one",
        )
    return out


def whole(value: float, parameter: str) -> int:
    """A whole number given as a float (TOML lists of numbers arrive as floats)."""
    if float(value) != int(value):
        raise ParameterError(parameter, f"expected whole numbers, got {value}")
    return int(value)


class ThrustAllocationController(Controller):
    """``VesselController`` as the run's controller node (kind ``thrust-allocation``), designed on
    the plant's continuous-time linearization about a heading ψ̄ = 0, eq. (23):

        A = [0 I; 0 −M⁻¹D],  B = [0; M⁻¹G],  E = [0; M⁻¹]   (b in the earth frame, P(ψ̄) = I),

    from which M = (E₂)⁻¹, D = −M A₂₂ and G = M B₂ (subscript 2: the velocity rows). It reads the
    ``fault_mask`` of its diagnosis node (the ``cofd`` kind) one tick late, and commands u_k.
    """

    kind = "thrust-allocation"
    continuous = True
    reports = (FAULT_MASK.name,)
    Params = VesselControllerParams
    OUTPUTS = ("x", "y", "psi", "u", "v", "r")

    def __init__(self, model: LinearModel, params: VesselControllerParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        missing = [name for name in self.OUTPUTS if name not in model.outputs]
        if missing or model.n != 6 or model.E.shape != (6, 3):
            raise ParameterError(
                "model",
                f"{self.kind} needs a planar vessel: states [η, ν], sensors {', '.join(self.OUTPUTS)} "
                f"and three earth-frame disturbance inputs (E = [0; M⁻¹]); "
                f"got states {model.states}, sensors {model.outputs}, {model.E.shape[1]} disturbances",
            )
        self._rows = [model.outputs.index(name) for name in self.OUTPUTS]
        M = np.linalg.inv(model.E[3:, :])
        self.law = VesselController(M, -M @ model.A[3:, 3:], M @ model.B[3:, :], self.sample_time, params)

    @classmethod
    def diagnostic_channels(cls, model_inputs: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        return list(VESSEL_DIAGNOSTICS)

    def step(self, y: np.ndarray, t: float, report: Mapping[str, float]) -> Command:
        u, diagnostics = self.law.step(np.asarray(y, dtype=float)[self._rows], t, int(report.get(FAULT_MASK.name, 0)))
        return Command(u, diagnostics)

    @classmethod
    def batched(cls, instances: Sequence[Any]) -> _VesselBatch:
        return _VesselBatch(instances)


class _VesselBatch:
    """K ``ThrustAllocationController`` instances of one design (``Controller.batched``). Each run's
    state stays in its own law; the runs on the nominal law (no fault reported, no thrust limits:
    one allocation basis for all) are stepped on arrays, the others by their own law's step."""

    def __init__(self, instances: Sequence[ThrustAllocationController]) -> None:
        self.controllers = list(instances)
        self.laws = [c.law for c in instances]
        first = self.laws[0]
        self.rows = instances[0]._rows
        self.N = first.cluster_basis if first.cluster_basis is not None else allocation_basis(first.m)
        self.allocation = pseudo_inverse(first.G @ self.N)  # what allocate() forms each call, the same numbers

    def step(self, y: np.ndarray, t: float, reports: Sequence[Mapping[str, float]]) -> tuple[np.ndarray, dict]:
        laws, first = self.laws, self.laws[0]
        y = np.asarray(y, dtype=float)[:, self.rows]
        masks = [int(report.get(FAULT_MASK.name, 0)) for report in reports]
        nominal = np.array(
            [first.limits is None and not (law.reported or law.active_mask or mask) for law, mask in zip(laws, masks)]
        )
        u = np.zeros((len(laws), first.m))
        values = np.zeros((len(laws), len(VESSEL_DIAGNOSTICS)))
        if nominal.any():
            rows = np.flatnonzero(nominal)
            u[rows], values[rows] = self._nominal([laws[r] for r in rows], y[rows])
        for r in np.flatnonzero(~nominal):
            u[r], found = laws[r].step(y[r], t, masks[r])
            values[r] = [found[d.name] for d in VESSEL_DIAGNOSTICS]
        return u, {d.name: values[:, i] for i, d in enumerate(VESSEL_DIAGNOSTICS)}

    def _nominal(self, laws: list[VesselController], y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``VesselController.step`` of runs without a fault report, on arrays (the same operations)."""
        first = laws[0]
        y = np.where(np.isfinite(y), y, np.stack([law.y_last for law in laws]))
        psi, nu = y[:, 2], y[:, 3:]
        for law, row in zip(laws, y):
            law.y_last = row
            if law.heading_ref is None:
                law.heading_ref = float(row[2])
            if law.speed_ref is None:
                law.speed_ref = row[3:5].copy()
        error = (psi - np.array([law.heading_ref for law in laws]) + np.pi) % (2 * np.pi) - np.pi  # _wrap
        heading_integral = np.array([law.heading_integral for law in laws]) + first.sample_time * error
        a_psi = -(first.kp * error + first.ki * heading_integral + first.kd * nu[:, 2])
        tau = np.matmul(first.D, nu[..., None])[..., 0]
        tau[:, 2] = tau[:, 2] + a_psi
        tau[:, :2] = tau[:, :2] + 0.0  # as + [0, 0, a_ψ] adds to every component
        u = np.matmul(self.N, np.matmul(self.allocation, tau[..., None]))[..., 0]
        unmet = np.matmul(first.G, u[..., None])[..., 0] - tau
        tau_error = np.array([float(np.linalg.norm(row)) for row in unmet])
        for law, e, integral, bound in zip(laws, tau_error, heading_integral.tolist(), tau.tolist()):
            if e <= 1e-6 * np.linalg.norm(bound):  # anti-windup: integrate only while τ_c is met
                law.heading_integral = integral
        clustered = float(first.cluster_basis is not None)
        zeros = np.zeros(len(laws))
        values = np.column_stack([tau, a_psi, error, tau_error, zeros + clustered, zeros, zeros])
        return u, values
