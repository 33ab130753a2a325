"""Fault-tolerant sensor reconciliation with unknown input observers (IJC 2018, Behzad et al.).

The virtual sensor of Fig. 2: a UIO estimates the plant state and the sensor bias, x = [x_p; b]
(eq. (7)–(8)), with gains designed by LMIs (``estimators.lmi``); a windowed constrained
least-squares estimator (50)–(53) estimates the sensor gains γ; the reconciliator returns the
virtual output ẑ = H_z C_y x̂_p (eq. (6)), free of the faults that corrupt y = Δ(γ) C_y x_p + F b.

- ``lpv-uio-sr``: Algorithm 1, the gain scheduled on ρ̂(γ̂) over the vertices of Γ (Theorem 1);
- ``lft-uio-sr``: Algorithm 2, one constant gain (Theorem 2);
- ``no-reconciliation``: the baseline ẑ = H_z y (and x̂ = C_y⁺ y), what Figure 9 calls falsified.

Coordinates. Gain faults scale what a sensor transmits, so the model (2), y = Δ(γ) C_y x_p + F b,
holds in the coordinates where the healthy readings are linear in the state without offset:
x_p = x − x_s with C x_s = −(y_op − C x_op) (x_s = 0 for sensors that read absolute values; the
operating point for transmitters zeroed there, like the three-tank's y1…y4, which makes x_p the
paper's deviation state). The linearization about (x_op, u_op) is then the affine model
x_p⁺ = A x_p + B u + c, c = (I − A)(x_op − x_s) − B u_op, a known input; x̂ = x̂_p + x_s is published.

Algorithm 1 step 5 and Algorithm 2 step 4 print Q_γ̂(t) next to T_γ̂(t−1); γ̂(t) is computed only
later (step 6), and T Ē = 0 needs T and Q at the same γ̂, so both use γ̂(t−1), as in eq. (10).
Step 8 returns H_z ŷ with ŷ = C̄_γ̂ x̂, which contains the estimated faults; the reconciled
virtual output of the problem statement is eq. (6), ẑ = H_z C_y x̂_p, and that is what is returned
(``zhat``). See docs/errata.md.
"""

from __future__ import annotations

from abc import abstractmethod
from collections import deque
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import scipy.optimize

from estimators.base import (
    Diagnostic,
    DiagnosticKind,
    Estimate,
    Estimator,
    ParameterError,
)
from estimators.lmi import (
    DesignError,
    LftDesign,
    LpvDesign,
    SensorFaultModel,
    box_coordinates,
    lft_uio_design,
    lpv_uio_design,
    uio_matrices,
)
from estimators.model import LinearModel

Matrix = tuple[tuple[float, ...], ...]


@dataclass(frozen=True)
class ReconciliationParams:
    Hz: tuple[float, ...] | None = None
    """The virtual output z = H_z C_y x_p, one weight per sensor (Sec. 4: [1/3, 1/3, 0, 1/3])."""
    F: tuple[float, ...] | None = None
    """Bias direction, one entry per sensor (eq. (2)); default all ones (eq. (59)-(60))."""
    gamma_min: float = 0.01
    """Lower corner γ̲ of the box Γ (Sec. 4: 0.01)."""
    gamma_max: float = 1.0
    """Upper corner γ̄ of Γ (Sec. 4: 1)."""
    design_gamma_min: float | None = None
    """γ̲ of the box the LMI design covers, if narrower than Γ (the LFT design of Theorem 2 is
    infeasible on the paper's full box: docs/three-tank.md); γ̂ is clipped to it."""
    window: int = 50
    """Horizon N of the parameter estimator (Sec. 4: 50)."""
    solver: str = "CLARABEL"
    """The SDP solver cvxpy uses for the LMIs."""
    x0: tuple[float, ...] | None = None
    """Initial plant-state estimate (absolute); None starts at the operating point."""
    pe_tol: float = 1e-6
    """Smallest σ_min/σ_max of the window's regressor for the excitation condition to count as met
    (``gain_estimator = "paper"``: of X̂_p, condition (55); ``"model"``: of the projected regressor);
    below it the ``pe`` diagnostic reads 0."""
    gain_estimator: str = "paper"
    """How γ̂ is estimated over the window: ``"paper"``, the QP (53) that regresses y on the UIO's own
    x̂_p (certainty equivalence, eq. (50)–(53)); ``"model"``, the consistency equations (50) with
    x_p constrained by the plant model (1) over the window, solved for 1/γ (ours: with four sensors
    for three levels and one bias the UIO's x̂ fits any γ̂, docs/three-tank.md)."""
    fit_tol: float = 0.05
    """``gain_estimator = "model"``: the largest relative residual of the window's equations for γ̂
    to be updated. Above it (a fault changed inside the window, or the inputs did not excite it) the
    previous γ̂ is kept. In the three-tank scenario consistent windows fit to 0.003 (median; 99 %
    below 0.048, the linearization's error), windows across a fault's onset to 0.065-2.5. Noise
    raises the floor (0.06 for 0.01 cm at N = 50, 0.015 at N = 200): set it to about twice the floor."""
    L: Matrix | None = None
    """lft-uio-sr: a precomputed gain (skips Theorem 2); the runner passes it to its nodes."""
    G: Matrix | None = None
    """lpv-uio-sr: precomputed G_i of Theorem 1, stacked by rows (l·(n+q) × (n+q))."""
    Y: Matrix | None = None
    """lpv-uio-sr: precomputed Y_i of Theorem 1, stacked by rows (l·(n+q) × m)."""
    multiplier: str = "scalar"
    """lft-uio-sr: the S-procedure multiplier of Theorem 2, "scalar" (eq. (42)) or "diagonal"."""


def _vector(value: tuple[float, ...] | None, size: int, name: str, default: float | None = None) -> np.ndarray:
    if value is None:
        if default is None:
            raise ParameterError(name, f"required: give {size} values, one per sensor")
        return np.full(size, default)
    array = np.asarray(value, dtype=float)
    if array.shape != (size,):
        raise ParameterError(name, f"expected {size} values (one per sensor), got {array.size}")
    return array


@dataclass(frozen=True)
class ModelWindow:
    """The consistency equations (50) over a window of N samples, with the plant model (1) as the
    link between samples; built once by ``model_window``, used every tick by ``window_gains``.

    Divide (2) by the gains, β_j = 1/γ_j: β_j y_j(k) − β_j F⁽ʲ⁾ b = C_y⁽ʲ⁾ x_p(k). With d_j = β_j F⁽ʲ⁾ b
    taken as a free offset per sensor, and x_p(k) = A^k x_p(0) + Σ_{i<k} A^(k−1−i) (B u(i) + E v(i))
    over the window k = 0 … N−1, every sample gives m equations linear in all the unknowns:

        Y(k) β − d − C_y A^k x_p(0) − Σ_{i<k} C_y A^(k−1−i) E v(i) = Σ_{i<k} C_y A^(k−1−i) B u(i),

    with Y(k) = diag(y(k)), each sensor's equations weighted by 1/‖C_y⁽ʲ⁾‖. The nuisance unknowns
    θ = (d, x_p(0), v(0), …, v(N−2)) enter through a fixed matrix Z, so β is the least-squares
    solution of W' Y β = W' r, where the columns of W are an orthonormal basis of the complement of
    range(Z).
    """

    nuisance: np.ndarray
    """Z, shape (N m, m + n + (N − 1) n_v): the columns of d, x_p(0) and v(0 … N−2), weighted."""
    response: np.ndarray
    """Σ_{i<k} C_y A^(k−1−i) B by sample and input, weighted, shape (N, m, N − 1, n_u)."""
    weight: np.ndarray
    """1/‖C_y⁽ʲ⁾‖ per sensor, shape (m,): each sensor's equations in units of the state, so that a
    sensor scaled up (10·h1) does not outweigh the others in the fit and in its residual."""
    complement: np.ndarray
    """W' reshaped (R, N, m): the (weighted) equations that the nuisance unknowns cannot satisfy."""
    forced: np.ndarray
    """W' applied to the forced response, (R, N − 1, n_u): contracted with u(0 … N−2) it is W' r."""


def _complement(Z: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the orthogonal complement of range(Z), as rows."""
    U, sv, _ = np.linalg.svd(Z, full_matrices=True)
    rank = int(np.sum(sv > sv[0] * 1e-10)) if sv.size and sv[0] > 0 else 0
    return U[:, rank:].T


def model_window(A: np.ndarray, B: np.ndarray, E: np.ndarray, C: np.ndarray, N: int) -> ModelWindow:
    """The window of ``ModelWindow`` for x⁺ = A x + B u + E v, y = Δ(γ) C x + F b.

    Shapes: A (n, n), B (n, n_u), E (n, n_v), C (m, n); N ≥ 2 samples.
    """
    n, m, nv, nu = A.shape[0], C.shape[0], E.shape[1], B.shape[1]
    powers = [np.eye(n)]
    for _ in range(N - 1):
        powers.append(A @ powers[-1])
    Z = np.zeros((N, m, m + n + (N - 1) * nv))
    forced = np.zeros((N, m, N - 1, nu))
    for k in range(N):
        Z[k, :, :m] = -np.eye(m)
        Z[k, :, m : m + n] = -C @ powers[k]
        for i in range(k):
            CA = C @ powers[k - 1 - i]
            Z[k, :, m + n + i * nv : m + n + (i + 1) * nv] = -CA @ E
            forced[k, :, i, :] = CA @ B
    weight = 1.0 / np.linalg.norm(C, axis=1)
    Z = (Z * weight[None, :, None]).reshape(N * m, -1)
    forced *= weight[None, :, None, None]
    W = _complement(Z).reshape(-1, N, m)
    return ModelWindow(Z, forced, weight, W, np.einsum("rkj,kjil->ril", W, forced))


def window_gains(
    window: ModelWindow, y: np.ndarray, u: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """The gains γ ∈ [lower, upper] that best explain a window of readings through the model.

    y (N, m): the readings (NaN where one did not arrive: its equation is dropped); u (N, n_u): the
    known inputs, u(k) acting from sample k to k + 1. Returns γ; the singular values of the
    column-normalized regressor W' Y, whose ratio measures how well the window excites the gains;
    and the relative residual ‖W' (Y β − r)‖ / ‖W' r‖, which is small only if one γ explains the
    whole window through the model (it is not, e.g., when a fault changes inside the window).
    The box 1/upper ≤ β ≤ 1/lower is imposed on β = 1/γ, where the problem is linear (BVLS).
    """
    missing = np.isnan(y)
    W, forced = window.complement, window.forced
    if missing.any():  # the complement of the nuisance columns within the equations that are left
        kept = ~missing.ravel()
        basis = _complement(window.nuisance[kept])
        W = np.zeros((len(basis), kept.size))
        W[:, kept] = basis
        W = W.reshape(len(basis), *y.shape)
        forced = np.einsum("rkj,kjil->ril", W, window.response)
    y0 = np.where(missing, 0.0, y) * window.weight
    regressor = np.einsum("rkj,kj->rj", W, y0)  # W' Y
    target = np.einsum("ril,il->r", forced, u[:-1])  # W' r
    scale = np.linalg.norm(regressor, axis=0)
    sv = np.linalg.svd(regressor / np.where(scale > 0, scale, 1.0), compute_uv=False)
    lo, hi = 1.0 / upper, 1.0 / lower
    beta = np.linalg.lstsq(regressor, target, rcond=None)[0]
    if np.any(beta < lo) or np.any(beta > hi):
        beta = scipy.optimize.lsq_linear(regressor, target, bounds=(lo, hi), method="bvls").x
    size = np.linalg.norm(target)
    residual = float(np.linalg.norm(regressor @ beta - target) / size) if size > 0 else np.inf
    return 1.0 / beta, sv, residual


class _Sample(NamedTuple):
    """One tick in the parameter estimator's window."""

    y: np.ndarray
    """The readings the UIO used (a missing one replaced by its prediction)."""
    x_p: np.ndarray
    b: np.ndarray
    measured: np.ndarray
    """The readings as received (NaN where one did not arrive)."""
    u: np.ndarray
    """The known inputs and the affine term's 1, [u; 1], held from this tick to the next."""


class _Reconciliator(Estimator):
    """What the three reconciliators share: H_z, F, the affine model in absolute coordinates."""

    Params = ReconciliationParams

    def __init__(self, model: LinearModel, params: ReconciliationParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        p = model.p
        self.Hz = _vector(params.Hz, p, "Hz")
        self.F = _vector(params.F, p, "F", 1.0)[:, None]
        offset = model.y_op - model.C @ model.x_op
        self.x_s = -np.linalg.lstsq(model.C, offset, rcond=None)[0]
        if np.max(np.abs(model.C @ self.x_s + offset)) > 1e-6 * (1.0 + np.max(np.abs(offset))) or np.any(model.D):
            raise ParameterError(
                "model", "sensor reconciliation needs sensors affine in the state with an offset in Im(C), and D = 0"
            )
        shifted = model.x_op - self.x_s
        self.c = shifted - model.A @ shifted - model.B @ model.u_op  # x_p⁺ = A x_p + B u + c

    @classmethod
    def diagnostic_channels(cls, states: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        return [Diagnostic("zhat", "", "virtual output estimate ẑ (eq. (6))", 1e4, 1e-4, DiagnosticKind.VIRTUAL_OUTPUT)]

    def _step(self, dy: np.ndarray, du: np.ndarray) -> Estimate:
        # Gain faults act on the readings as transmitted: work on y and u themselves.
        m = self.model
        estimate = self._absolute_step(dy + m.y_op, du + m.u_op)
        return Estimate(estimate.x - m.x_op, estimate.diagnostics)

    @abstractmethod
    def _absolute_step(self, y: np.ndarray, u: np.ndarray) -> Estimate:
        """One tick on the transmitted readings y and inputs u; returns the absolute estimate."""


class NoReconciliation(_Reconciliator):
    """The uncorrected virtual output ẑ = H_z y, and x̂ = C_y⁺ y (least squares on the raw readings)."""

    kind = "no-reconciliation"

    def __init__(self, model: LinearModel, params: ReconciliationParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        self.C_pinv = np.linalg.pinv(model.C)

    def _absolute_step(self, y: np.ndarray, u: np.ndarray) -> Estimate:
        available = ~np.isnan(y)
        y0 = np.where(available, y, 0.0)
        x = (
            np.linalg.lstsq(self.model.C[available], y[available], rcond=None)[0] + self.x_s
            if available.any()
            else self.model.x_op
        )
        return Estimate(x, {"zhat": float(self.Hz @ y0)})


class UioReconciliator(_Reconciliator):
    """UIO (10)–(14) + parameter estimator (50)–(53) + reconciliator (6): Algorithms 1 and 2."""

    form = "pinv"
    design_free = frozenset({"Hz", "window", "x0", "pe_tol", "gain_estimator", "fit_tol"})

    def __init__(self, model: LinearModel, params: ReconciliationParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        n, p = model.n, model.p
        if model.E.shape[1] == 0:
            raise ParameterError(
                "model",
                "the plant declares no unknown input: a UIO needs E (plant disturbances or [plant.state_space] E)",
            )
        if not 0.0 < params.gamma_min < params.gamma_max <= 1.0:
            raise ParameterError(
                "gamma_min", f"Γ = [{params.gamma_min}, {params.gamma_max}]^m needs 0 < γ̲ < γ̄ ≤ 1 (eq. (5))"
            )
        design_min = params.gamma_min if params.design_gamma_min is None else params.design_gamma_min
        if not params.gamma_min <= design_min < params.gamma_max:
            raise ParameterError(
                "design_gamma_min", f"must lie in [gamma_min, gamma_max) = [{params.gamma_min}, {params.gamma_max})"
            )
        if params.window < 2:
            raise ParameterError("window", "the parameter estimator needs N ≥ 2 samples")
        if params.gain_estimator not in ("paper", "model"):
            raise ParameterError("gain_estimator", f'{params.gain_estimator!r}: use "paper" (eq. (53)) or "model"')
        self.aug = SensorFaultModel(model.A, np.hstack([model.B, self.c[:, None]]), model.E, model.C, self.F)
        self.lower, self.upper = np.full(p, design_min), np.full(p, params.gamma_max)
        self.Abar, self.Bbar = self.aug.Abar, self.aug.Bbar
        self._design()
        x0 = model.x_op if params.x0 is None else np.asarray(params.x0, dtype=float)
        if x0.shape != (n,):
            raise ParameterError("x0", f"expected {n} values ({', '.join(model.states)}), got {x0.size}")
        self.x_bar0 = np.concatenate([x0 - self.x_s, np.zeros(self.aug.q)])
        self.model_window = (
            None
            if params.gain_estimator == "paper"
            else model_window(model.A, self.aug.B, model.E, model.C, params.window)
        )
        self.reset()

    def reset(self) -> None:
        self.gamma = np.ones(self.model.p)  # Algorithm 1/2, initialization step 3: Δ(γ̂) = I
        self.x_hat: np.ndarray | None = None
        self.previous: tuple[np.ndarray, np.ndarray] | None = None  # (y, u) of the previous tick
        self.history: deque[_Sample] = deque(maxlen=self.params.window)
        self.pe = 0.0
        self.fit = 0.0

    # -- design ---------------------------------------------------------------------------------

    @abstractmethod
    def _design(self) -> None:
        """Solve (or take from the parameters) the LMI design of the observer gain."""

    @abstractmethod
    def gain(self, gamma: np.ndarray) -> np.ndarray:
        """The observer gain L at γ̂, shape (n + q, m)."""

    def _solve(self, design, **kwargs):
        try:
            return design(self.aug, self.lower, self.upper, solver=self.params.solver, **kwargs)
        except DesignError as error:
            raise ParameterError("model", f"{error} (the box the design covers is set by design_gamma_min)") from None

    # -- the on-line phase --------------------------------------------------------------------

    def _absolute_step(self, y: np.ndarray, u: np.ndarray) -> Estimate:
        gamma = self.gamma  # γ̂(t−1)
        Q, T = uio_matrices(self.aug, gamma, form=self.form)
        Cbar = self.aug.Cbar(gamma)
        u_bar = np.append(u, 1.0)
        if self.x_hat is None:  # t = 0: the UIO's own reconstruction from y(0) about x̂₀
            prior = self.x_bar0
            x_next = T @ prior
        else:
            y_prev, u_prev = self.previous
            prior = self.Abar @ self.x_hat + self.Bbar @ u_prev
            x_next = T @ prior + self.gain(gamma) @ (y_prev - Cbar @ self.x_hat)  # eq. (10)
        # A reading that did not arrive is replaced by its prediction, C̄ times the a-priori state.
        measured = y
        y = np.where(np.isnan(y), Cbar @ prior, y)
        self.x_hat = x_next + Q @ y
        self.previous = (y, u_bar)
        n = self.model.n
        x_p, b = self.x_hat[:n], self.x_hat[n:]
        self.history.append(_Sample(y, x_p.copy(), b.copy(), measured, u_bar))
        if len(self.history) == self.params.window:
            self.gamma = self._estimate_gamma() if self.model_window is None else self._estimate_gamma_on_the_model()
        z = float(self.Hz @ (self.model.C @ x_p))  # eq. (6)
        diagnostics = {f"gamma_{name}": float(g) for name, g in zip(self.model.outputs, self.gamma)}
        diagnostics |= {name: float(v) for name, v in zip(self._bias_names(self.aug.q), b)}
        diagnostics |= {"zhat": z, "pe": self.pe, "fit": min(self.fit, 999.0)}
        return Estimate(x_p + self.x_s, diagnostics)

    def _estimate_gamma(self) -> np.ndarray:
        """The QP (53) over the window (51)–(52).

        φ(t) stacks X(t−i) = diag(C_y⁽ʲ⁾ x̂_p(t−i)), so φᵀφ is diagonal and (53) separates into one
        scalar problem per sensor, min Σ_i (r_ij − γ_j s_ij)² over γ̲ ≤ γ_j ≤ γ̄, with
        s_ij = C_y⁽ʲ⁾ x̂_p(t−i) and r_ij = y_j(t−i) − F⁽ʲ⁾ b̂(t−i); each is solved exactly by
        clipping its unconstrained minimizer. A sensor whose regressor column is zero (rank φ < m,
        condition (54)) keeps its previous estimate.
        """
        ys, xs, bs = (np.array([getattr(sample, field) for sample in self.history]) for field in ("y", "x_p", "b"))
        s = xs @ self.model.C.T  # (N, m)
        r = ys - bs @ self.F.T
        energy = np.sum(s * s, axis=0)
        gamma = self.gamma.copy()
        identified = energy > 0.0
        gamma[identified] = np.sum(r * s, axis=0)[identified] / energy[identified]
        gamma = np.clip(gamma, self.lower, self.upper)
        size = np.linalg.norm(r)
        self.fit = float(np.linalg.norm(r - gamma * s) / size) if size > 0 else 0.0
        # Condition (55): rank X̂_p = n, as the ratio of extreme singular values.
        sv = np.linalg.svd(xs, compute_uv=False)
        self.pe = self._excitation(sv, self.model.n)
        return gamma

    def _estimate_gamma_on_the_model(self) -> np.ndarray:
        """γ̂ from the window through the model (``window_gains``), within Γ. A window that does not
        excite the gains (σ ratio below ``pe_tol``) or that no single γ explains (relative residual
        above ``fit_tol``) keeps the previous estimate."""
        ys, us = (np.array([getattr(sample, field) for sample in self.history]) for field in ("measured", "u"))
        gamma, sv, self.fit = window_gains(self.model_window, ys, us, self.lower, self.upper)
        self.pe = self._excitation(sv, self.model.p)
        return gamma if self.pe > 0.0 and self.fit <= self.params.fit_tol else self.gamma

    def _excitation(self, sv: np.ndarray, rank: int) -> float:
        """σ_min/σ_max of a regressor that must have ``rank`` columns' worth of excitation; 0 when
        that ratio is below ``pe_tol`` (the condition fails)."""
        ratio = float(sv[-1] / sv[0]) if len(sv) >= rank and sv[0] > 0 else 0.0
        return ratio if ratio >= self.params.pe_tol else 0.0

    @staticmethod
    def _bias_names(q: int) -> list[str]:
        return ["bhat"] if q == 1 else [f"bhat{i + 1}" for i in range(q)]

    @classmethod
    def diagnostic_channels(cls, states: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        return [
            *[
                Diagnostic(
                    f"gamma_{name}",
                    "",
                    f"estimated effectiveness γ̂ of sensor {name} (eq. (53))",
                    2.0,
                    1e-6,
                    DiagnosticKind.GAIN_ESTIMATE,
                    name,
                )
                for name in outputs
            ],
            Diagnostic(
                "bhat", "", "estimated sensor bias b̂ (augmented state, eq. (7))", 1e4, 1e-4, DiagnosticKind.BIAS
            ),
            *super().diagnostic_channels(states, outputs),
            Diagnostic(
                "pe",
                "",
                "persistence of excitation σ_min/σ_max of the window's regressor (condition (55); 0: not met)",
                2.0,
                1e-9,
                DiagnosticKind.EXCITATION,
            ),
            Diagnostic(
                "fit",
                "",
                "relative residual of the window's equations for γ̂ ((53), or the model window)",
                1e3,
                1e-6,
                DiagnosticKind.FIT,
            ),
        ]


class LpvUioReconciliator(UioReconciliator):
    """Algorithm 1 (LPV-UIO-SR): L(ρ̂) = G(ρ̂)⁻¹ Y(ρ̂) from Theorem 1, T and Q from eq. (14)."""

    kind = "lpv-uio-sr"
    form = "pinv"

    def _design(self) -> None:
        p = self.params
        if p.G is not None and p.Y is not None:
            nx, l = self.aug.n + self.aug.q, 2**self.model.p
            G, Y = np.asarray(p.G, dtype=float), np.asarray(p.Y, dtype=float)
            if G.shape != (l * nx, nx) or Y.shape != (l * nx, self.model.p):
                raise ParameterError("G", f"precomputed G and Y must be {l * nx}×{nx} and {l * nx}×{self.model.p}")
            self.G_vertices, self.Y_vertices, self.design = G.reshape(l, nx, nx), Y.reshape(l, nx, self.model.p), None
        else:
            self.design: LpvDesign | None = self._solve(lpv_uio_design)
            self.G_vertices, self.Y_vertices = self.design.G, self.design.Y

    def gain(self, gamma: np.ndarray) -> np.ndarray:
        rho = box_coordinates(gamma, self.lower, self.upper)
        return np.linalg.solve(np.tensordot(rho, self.G_vertices, axes=1), np.tensordot(rho, self.Y_vertices, axes=1))

    def design_params(self) -> dict[str, Any]:
        l, nx = self.G_vertices.shape[:2]
        return {"G": self.G_vertices.reshape(l * nx, nx).tolist(), "Y": self.Y_vertices.reshape(l * nx, -1).tolist()}


class LftUioReconciliator(UioReconciliator):
    """Algorithm 2 (LFT-UIO-SR): the constant gain L of Theorem 2, Q = Ē G⁺ Δ⁻¹(γ̂) of eq. (60)."""

    kind = "lft-uio-sr"
    form = "lft"

    def _design(self) -> None:
        if self.params.L is not None:
            self.L, self.design = np.asarray(self.params.L, dtype=float), None
            nx = self.aug.n + self.aug.q
            if self.L.shape != (nx, self.model.p):
                raise ParameterError("L", f"expected a {nx}×{self.model.p} gain, got {self.L.shape}")
        else:
            if self.params.multiplier not in ("scalar", "diagonal"):
                raise ParameterError("multiplier", f'{self.params.multiplier!r}: use "scalar" (eq. (42)) or "diagonal"')
            self.design: LftDesign | None = self._solve(lft_uio_design, multiplier=self.params.multiplier)
            self.L = self.design.L

    def gain(self, gamma: np.ndarray) -> np.ndarray:
        return self.L

    def design_params(self) -> dict[str, Any]:
        return {"L": self.L.tolist()}
