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

The design's plain functions are ``estimators.cofd_design`` (``cofd_observer``, ``cofd_family``,
``cluster_directions``, ``residual_bounds``, ``fault_signatures``); the isolation logic is
``estimators.isolation``. ``COFDDiagnosis`` is the estimator node (kind ``cofd``), ``COFDBatch``
K of them stepped together. docs/vessel-fdi.md has the derivations
and the choices the paper leaves open.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimators.allocation import FAULT_MASK, MAX_THRUSTERS, cluster_matrix, input_groups, whole
from estimators.base import Estimate, Estimator, ParameterError
from estimators.batched import BatchEstimate, DeviationBatch, mv, norms
from estimators.cofd_design import (
    SHIP_CLUSTER_FAMILY,
    SHIP_F,
    SHIP_FAMILY,
    SHIP_GROUPS,
    SHIP_PAIRS,
    DesignError,
    cluster_directions,
    cofd_family,
    fault_signatures,
    residual_bounds,
)
from estimators.diagnostics import Diagnostic, DiagnosticKind
from estimators.isolation import Isolation, unisolable
from estimators.model import LinearModel
from estimators.rotating_frame import FrameTerms
from estimators.thresholds import FORCE, MOMENT, DeclaredEnvironment, centred_thresholds, residual_test
from estimators.uio import discretize

# -- the diagnosis node ---------------------------------------------------------------------------

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
        self.isolation = Isolation(self.signatures, self.hypotheses)
        self.ell = max(len(J) for J in family)
        self.thresholds, centred = self._thresholds(E)
        self.test = residual_test(
            self.observers, model.C, E, params, self.thresholds, centred, self.sample_time, params.margin
        )
        self.discrete = [discretize(o, model.B, self.sample_time) for o in self.observers]
        self.frame = FrameTerms(model, self.observers, self.sample_time) if params.rotating_frame else None
        self.x_init = None if params.x0 is None else np.asarray(params.x0, dtype=float) - model.x_op
        if self.x_init is not None and self.x_init.shape != (model.n,):
            raise ParameterError("x0", f"expected {model.n} values, got {self.x_init.size}")
        self._measured = np.linalg.pinv(model.C)
        self.z: list[np.ndarray] | None = None
        self.y_prev = np.zeros(model.p)
        self.u_prev = np.zeros(model.m)
        self.candidate = np.array([-1])  # the hypothesis isolated at the last tick (an index; −1: none) ...
        self.candidate_since = np.zeros(1)  # ... since when: one run's row of ``_diagnose``'s state
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
        return flat, centred_thresholds(self.observers, C, E, params, self.sample_time, self.ell, params.margin)

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

    def _constraints_met(self, u: np.ndarray) -> np.ndarray:
        """Whether each run's commands u (K, m) obey the cluster constraints, u ∈ span N (eq. (24)),
        to 0.1 % of |u|∞ (they arrive quantized over the bus); (K,) booleans.

        The K least-squares fits are one call with K right-hand sides, which LAPACK need not round
        as it rounds one: a run whose test lies within 10⁻⁶ of its tolerance (the fits agree to
        about κ(N) ε |u|; N's columns are orthogonal, κ(N) = the ratio of their lengths) or whose u
        is not finite is tested again by itself, so that every answer is the one-run fit's."""
        if self.N is None:
            return np.ones(len(u), dtype=bool)
        fit = np.linalg.lstsq(self.N, u.T, rcond=None)[0].T
        off = np.abs(u - mv(self.N, fit)).max(axis=1)
        size = np.abs(u).max(axis=1)
        tolerance = 1e-3 * np.where(1e-9 > size, 1e-9, size)  # Python's max(|u|∞, 1e-9)
        met = off <= tolerance
        if len(u) > 1:
            for k in np.flatnonzero(~(np.abs(off - tolerance) > 1e-6 * tolerance)):  # near, or NaN
                met[k] = self._constraints_met(u[k : k + 1])[0]
        return met

    def _diagnose(
        self, t: float, fired: np.ndarray, u: np.ndarray, candidate: np.ndarray, since: np.ndarray, isolated: np.ndarray
    ) -> np.ndarray:
        """Isolation and persistence at time t for K runs: each run's fired components (K,
        observers, components) point to a fault while its commands u (K, m) obey (24); the same
        fault isolated tick after tick for ``persistence`` seconds latches its thrusters in
        ``isolated`` (K, groups). ``candidate`` and ``since`` (K,) are updated in place; returns
        whether each run's commands obey (24)."""
        met = self._constraints_met(u)
        found = np.where(met, self.isolation(fired), -1)
        since[found != candidate] = t
        candidate[:] = found
        if (found >= 0).any():  # else nothing to latch: the usual tick
            ready = (found >= 0) & (t - since >= self.params.persistence - 1e-9)
            isolated |= ready[:, None] & self.isolation.members[found]
        return met

    @classmethod
    def batched(cls, instances: Sequence[Any]) -> COFDBatch:
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
        u = (self.u_prev + model.u_op)[None]  # (24) constrains the absolute inputs
        state = self.candidate, self.candidate_since, self.isolated[None]
        constraints_met = self._diagnose(self.t, fired[None], u, *state)[0]
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


def check_declared(params: COFDParams, E: np.ndarray, sample_time: float) -> None:
    """The declared environment must act on the ship's three unknown inputs and fit in the paper's
    class, |b| + |d| ≤ ε (``disturbance_bound``), which the flat thresholds hold for."""
    params.check(sample_time)
    if E.shape[1] != len(FORCE) + len(MOMENT):
        raise ParameterError(
            "current",
            f"the declared environment acts on three unknown inputs (b_x, b_y, b_n); the model's E has {E.shape[1]}",
        )
    if params.bound > params.disturbance_bound:
        raise ParameterError(
            "disturbance_bound",
            f"the declared environment reaches |b| + |d| ≤ {params.bound:g} (current + hypot(wave_force, "
            f"wave_moment) + model_error) > ε = {params.disturbance_bound:g}: raise disturbance_bound or declare a "
            "calmer sea",
        )


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


# -- K runs at once ---------------------------------------------------------------------------------


class COFDBatch(DeviationBatch):
    """K ``COFDDiagnosis`` instances of one design (``COFDDiagnosis.batched``): its observers,
    residual test and rotating-frame terms on arrays with a leading run axis, bit for bit each run's
    own step.

    The observers' recursions, the thresholds' inertial allowance and the residual test are the same
    arithmetic in every run (``estimators.batched.mv`` and ``norms``, elementwise operations, NumPy's
    ``cos`` and ``sin`` on columns); the constraint (24) on each run's commands, the isolation of its
    fired components and the persistence before it latches them are ``COFDDiagnosis._diagnose``, which
    the single step calls with K = 1."""

    def __init__(self, instances: Sequence[COFDDiagnosis]) -> None:
        super().__init__(instances)
        first = self.first = instances[0]
        self.z: list[np.ndarray] | None = None
        if any(e.z is not None for e in instances):
            states: list[Any] = [e.z for e in instances]
            self.z = [np.stack([z[h] for z in states]) for h in range(len(first.observers))]
        self.y_prev = np.stack([e.y_prev for e in instances])
        self.u_prev = np.stack([e.u_prev for e in instances])
        self.t = first.t
        self.candidate = np.concatenate([e.candidate for e in instances])
        self.candidate_since = np.concatenate([e.candidate_since for e in instances])
        self.isolated = np.stack([e.isolated for e in instances])
        test = first.test
        tests: list[Any] = [e.test for e in instances]
        self.total = np.stack([t.total for t in tests])
        self.count = test.count
        self.mean = None if test.mean is None else np.stack([t.mean for t in tests])
        allowances: list[Any] = [t.allowance for t in tests]
        if test.allowance is not None:
            self.q = [np.stack([a.q[h] for a in allowances]) for h in range(len(test.allowance.q))]
            self.a_prev = None if test.allowance.y_prev is None else np.stack([a.y_prev for a in allowances])

    def _step(self, dy: np.ndarray, du: np.ndarray) -> BatchEstimate:
        model, first = self.model, self.first
        runs = len(dy)
        y = np.where(np.isnan(dy), self.y_prev, dy)
        if self.z is None:
            x0 = mv(np.linalg.pinv(model.C), y) if first.x_init is None else first.x_init
            self.z = [x0 - mv(o.H, y) for o in first.observers]
        else:
            self.t += first.sample_time
            frame = self._frame(self.y_prev, y) if first.frame else [0.0] * len(self.z)
            self.z = [
                mv(Phi, z) + mv(Gu, self.u_prev) + mv(Gy0, self.y_prev) + mv(Gy1, y) + kinematics
                for z, (Phi, Gu, Gy0, Gy1), kinematics in zip(self.z, first.discrete, frame)
            ]
        x_hats = [z + mv(o.H, y) for z, o in zip(self.z, first.observers)]
        r = np.stack([(y - mv(model.C, x))[:, : first.ell] for x in x_hats], axis=1)
        residuals, thresholds = self._test(r, y)
        fired = np.abs(residuals) > thresholds
        state = self.candidate, self.candidate_since, self.isolated
        met = first._diagnose(self.t, fired, self.u_prev + model.u_op, *state)
        self.y_prev, self.u_prev = y, du
        shown = np.zeros((runs, 2, MAX_OBSERVERS, MAX_COMPONENTS))
        shown[:, 0, : len(first.observers), : first.ell] = residuals
        shown[:, 1, : len(first.observers), : first.ell] = thresholds
        groups = self.isolated.shape[1]
        isolated = np.zeros((runs, MAX_THRUSTERS))
        isolated[:, :groups] = self.isolated
        flat = shown.reshape(runs, 2, -1)
        diagnostics = {RESIDUAL.named(c): flat[:, 0, i] for i, c in enumerate(COMPONENTS)}
        diagnostics |= {THRESHOLD.named(c): flat[:, 1, i] for i, c in enumerate(COMPONENTS)}
        diagnostics[ALARM.name] = fired.any(axis=(1, 2)).astype(float)
        diagnostics |= {ISOLATED.named(j): isolated[:, i] for i, j in enumerate(THRUSTERS)}
        diagnostics[FAULT_MASK.name] = (self.isolated * (1 << np.arange(groups))).sum(axis=1).astype(float)
        diagnostics[CONSTRAINTS_MET.name] = met.astype(float)
        return BatchEstimate(mv(first._measured, y), diagnostics)

    def _frame(self, y_prev: np.ndarray, y: np.ndarray) -> list[np.ndarray]:
        """``FrameTerms.__call__`` for K runs."""
        frame = self.first.frame
        assert frame is not None
        before, after = _kinematic_terms(y_prev + frame.y_op), _kinematic_terms(y + frame.y_op)
        return [mv(G0, before) + mv(G1, after) for G0, G1 in frame.gains]

    def _test(self, r: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``ResidualTest.__call__`` for K runs: r of shape (K, observers, components)."""
        test = self.first.test
        extra = self._allowance(y) if test.allowance is not None else np.zeros_like(r)
        if test.centred is None:
            return r, test.flat + extra
        if self.mean is None and self.t >= test.end:
            self.mean = self.total / max(self.count, 1)
        if self.mean is None:
            if self.t >= test.start:
                self.total += np.stack((r, extra), axis=1)
                self.count += 1
            return r, test.flat + extra
        return r - self.mean[:, 0], test.centred + extra + self.mean[:, 1]

    def _allowance(self, y: np.ndarray) -> np.ndarray:
        """``InertialAllowance.__call__`` for K runs (each run's force norm as its own)."""
        allowance = self.first.test.allowance
        assert allowance is not None
        if self.a_prev is None:
            a = np.zeros(len(y))
        else:
            a = norms(mv(allowance.rate, y - self.a_prev))
        self.a_prev = y
        self.q = [d * q + g * a[:, None] for q, d, g in zip(self.q, allowance.decay, allowance.step)]
        return np.stack([mv(w, q) for w, q in zip(allowance.weights, self.q)], axis=1)


def _kinematic_terms(y: np.ndarray) -> np.ndarray:
    """``rotating_frame.kinematic_terms`` of each row y = [x, y, ψ, u, v, r]."""
    psi, u, v, r = y[:, 2], y[:, 3], y[:, 4], y[:, 5]
    c, s = np.cos(psi), np.sin(psi)
    zero = np.zeros(len(y))
    return np.stack([(c - 1.0) * u - s * v, s * u + (c - 1.0) * v, zero, r * v, -r * u, zero], axis=1)
