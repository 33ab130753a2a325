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

import functools
import itertools
from abc import abstractmethod
from collections import deque
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import scipy.optimize
import scipy.special

from estimators.base import Diagnostic, DiagnosticKind, Estimate, Estimator, ParameterError
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
    x_p constrained by the plant model (1) over the window, solved for 1/γ every tick (ours: with four
    sensors for three levels and one bias the UIO's x̂ fits any γ̂, docs/three-tank.md); ``"test"``,
    the same equations whitened by ``noise_std``, with γ̂ changed only when a χ² test rejects it
    (``decide_gains``)."""
    noise_std: float | tuple[float, ...] | None = None
    """``gain_estimator = "test"``: the standard deviation σ_j of each sensor's white measurement
    noise, in the sensor's unit (one number: the same for all), added before the gain. Required by the
    test: its threshold follows from it. On a plant the linear model does not match exactly (the
    MJCF three-tank), it must also cover the model's error (docs/three-tank.md)."""
    alpha: float = 1e-6
    """``gain_estimator = "test"``: the false-alarm probability of each window's χ² test, the
    probability that a window whose gains did not change rejects them."""
    min_window: int = 10
    """``gain_estimator = "test"``: the fewest samples after a change that may identify new gains."""
    se_tol: float = 0.05
    """``gain_estimator = "test"``: the largest standard error of a gain estimate, 1/‖P⊥ D Y_j‖, for a
    window to count as exciting: a window that resolves some gain worse than this identifies none
    (the ``pe`` diagnostic reads 0) and γ̂ is kept."""
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


def _stacked_window(
    A: np.ndarray, B: np.ndarray, E: np.ndarray, C: np.ndarray, N: int
) -> tuple[np.ndarray, np.ndarray]:
    """The N samples' equations of x⁺ = A x + B u + E v, y = C x + b, stacked: sample k reads
    0 = Z_k [b; x_0; v_0 … v_{N-2}] + y_k − Σ_{i<k} C A^{k-1-i} B u_i, with ``forced[k, :, i]`` =
    C A^{k-1-i} B. Shapes: Z (N, m, m + n + (N−1) n_v), forced (N, m, N−1, n_u)."""
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
    return Z, forced


def model_window(A: np.ndarray, B: np.ndarray, E: np.ndarray, C: np.ndarray, N: int) -> ModelWindow:
    """The window of ``ModelWindow`` for x⁺ = A x + B u + E v, y = Δ(γ) C x + F b.

    Shapes: A (n, n), B (n, n_u), E (n, n_v), C (m, n); N ≥ 2 samples.
    """
    m = C.shape[0]
    Z, forced = _stacked_window(A, B, E, C, N)
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


# -- the gain test (ours: γ̂ changes only on evidence; docs/three-tank.md, "The gain test") ----------


@dataclass(frozen=True)
class GainTestWindow:
    """The consistency equations (50) of the last L samples, L = ``min_window`` … N, linked by the
    plant model (1) as in ``ModelWindow``, but whitened by the readings' noise level; built once by
    ``gain_test_window``, used every tick by ``window_system``.

    With white measurement noise n_j(k) ~ N(0, σ_j²) added before the gain, y = Δ(γ)(C_y x_p + n) + F b
    (the testbed adds noise first, then the faults), sensor j's equation

        β_j y_j(k) − d_j − C_y⁽ʲ⁾ x_p(k) = n_j(k),    β_j = 1/γ_j, d_j = β_j F⁽ʲ⁾ b,

    divided by σ_j, has a unit normal error. Projecting off the nuisance unknowns θ = (d, x_p(0),
    v(0 … L−2)) leaves the residual P⊥ D (Y β − r) = P⊥ e at the true β, e ~ N(0, I): its squared
    norm is χ² with L m − rank(Z_L) degrees of freedom, whatever the state, the inputs, the unknown
    input and the bias. The sub-window of the last L samples is the top-left block of the N-sample
    window (the model is time-invariant), so one Z serves every L.
    """

    weight: np.ndarray
    """D = 1/σ_j per sensor, shape (m,)."""
    nuisance: np.ndarray
    """Z over N samples, whitened, shape (N, m, m + n + (N − 1) n_v)."""
    columns: tuple[int, ...]
    """Per L = min_window … N: the columns of Z that the last L samples involve, m + n + (L − 1) n_v."""
    bases: tuple[np.ndarray, ...]
    """Per L = min_window … N: an orthonormal basis of range(Z_L), shape (L m, rank Z_L)."""
    forced: np.ndarray
    """Σ_{i<k} C_y A^(k−1−i) B by sample and input, whitened, shape (N, m, N − 1, n_u)."""
    min_window: int
    """The shortest sub-window that may identify the gains after a change."""

    @property
    def window(self) -> int:
        return int(self.forced.shape[0])


def gain_test_window(
    A: np.ndarray, B: np.ndarray, E: np.ndarray, C: np.ndarray, noise_std: np.ndarray, N: int, min_window: int
) -> GainTestWindow:
    """The ``GainTestWindow`` of x⁺ = A x + B u + E v, y = Δ(γ)(C x + n) + F b, n_j ~ N(0, σ_j²).

    Shapes: A (n, n), B (n, n_u), E (n, n_v), C (m, n), noise_std (m,); 2 ≤ min_window ≤ N.
    """
    n, m, nv = A.shape[0], C.shape[0], E.shape[1]
    Z, forced = _stacked_window(A, B, E, C, N)
    weight = 1.0 / np.asarray(noise_std, dtype=float)
    Z *= weight[None, :, None]
    forced *= weight[None, :, None, None]
    columns = tuple(m + n + (L - 1) * nv for L in range(min_window, N + 1))
    bases = tuple(
        _range_basis(Z[:L, :, :c].reshape(L * m, c)) for L, c in zip(range(min_window, N + 1), columns, strict=True)
    )
    return GainTestWindow(weight, Z, columns, bases, forced, min_window)


def _range_basis(Z: np.ndarray) -> np.ndarray:
    """An orthonormal basis of range(Z), as columns."""
    U, sv, _ = np.linalg.svd(Z, full_matrices=False)
    rank = int(np.sum(sv > sv[0] * 1e-10)) if sv.size and sv[0] > 0 else 0
    return U[:, :rank]


class WindowSystem(NamedTuple):
    """A window's whitened equations with the nuisance unknowns projected out, in the reduced form
    of least squares: T(β) = ‖factor β − rotated‖² + rest, χ²(dof) at the true β."""

    factor: np.ndarray
    """R of the QR factorization of the projected regressor P⊥ D Y, shape (m, m)."""
    rotated: np.ndarray
    """Qᵀ P⊥ D r, shape (m,): the projected target in the regressor's column space."""
    rest: float
    """The part of ‖P⊥ D r‖² no β can explain."""
    dof: int
    """Equations less the rank of the nuisance columns: the residual's degrees of freedom at the
    true β."""


def window_system(
    window: GainTestWindow, y: np.ndarray, u: np.ndarray, change: int | None = None, before: np.ndarray | None = None
) -> WindowSystem:
    """The system of the last L = len(y) samples, min_window ≤ L ≤ N: readings y (L, m), NaN where
    one did not arrive (its equation is dropped), and inputs u (L, n_u), u(k) held from k to k + 1.

    With ``change`` = c (0 < c < L), the gains change at sample c: samples k < c have the known
    β = ``before`` (their terms move to the target), and the regressor holds only samples k ≥ c.
    Each sensor's offset d_j may jump at c as well (a bias step, or d_j = β_j F⁽ʲ⁾ b with a new
    β_j): m more nuisance columns, projected out with the others."""
    L, m = y.shape
    index = L - window.min_window
    kept = ~np.isnan(y).ravel()
    rows = np.arange(L * m)
    Y = np.zeros((L * m, m))
    Y[rows, np.tile(np.arange(m), L)] = (np.where(np.isnan(y), 0.0, y) * window.weight).ravel()
    r = np.einsum("kjil,il->kj", window.forced[:L, :, : L - 1], u[:-1]).ravel()
    if change is not None:
        assert before is not None and 0 < change < L
        after = np.repeat(np.arange(L), m) >= change
        r = r - np.where(after, 0.0, Y @ before)
        Y[~after] = 0.0
    if kept.all():
        Q = window.bases[index]
    else:  # the range of the nuisance columns within the equations that are left
        Q = _range_basis(window.nuisance[:L, :, : window.columns[index]].reshape(L * m, -1)[kept])
        Y, r, rows = Y[kept], r[kept], rows[kept]
    Y = Y - Q @ (Q.T @ Y)
    r = r - Q @ (Q.T @ r)
    dof = len(r) - Q.shape[1]
    if change is not None:
        J = np.zeros((len(r), m))  # the offsets' jumps, whitened
        jumped = rows // m >= change
        J[jumped, rows[jumped] % m] = window.weight[rows[jumped] % m]
        G = _range_basis(J - Q @ (Q.T @ J))
        Y = Y - G @ (G.T @ Y)
        r = r - G @ (G.T @ r)
        dof -= G.shape[1]
    basis, factor = np.linalg.qr(Y)
    rotated = basis.T @ r
    return WindowSystem(factor, rotated, float(max(r @ r - rotated @ rotated, 0.0)), int(dof))


@functools.lru_cache(maxsize=1024)
def _chi2_quantile(alpha: float, dof: int) -> float:
    """The (1 − α) quantile of χ²(dof): the threshold of a test at level α."""
    return float(scipy.special.chdtri(dof, alpha))


def chi2_statistic(system: WindowSystem, beta: np.ndarray) -> float:
    """T(β) = ‖P⊥ D (Y β − r)‖², χ²(dof) when β is the true 1/γ."""
    residual = system.factor @ beta - system.rotated
    return float(residual @ residual) + system.rest


def gain_standard_errors(system: WindowSystem) -> np.ndarray:
    """The standard error of each β̂_j fitted alone (the others given), 1/‖P⊥ D Y_j‖: how well the
    window resolves a change of that sensor's gain (γ̂ = 1/β̂ has about the same near γ = 1)."""
    norms = np.linalg.norm(system.factor, axis=0)
    return np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), np.inf)


class GainHypothesis(NamedTuple):
    """A hypothesis about a window's gains: those in ``free`` changed to unknown values, each of the
    others is either as before (the previous γ̂) or back to 1."""

    beta: np.ndarray
    """β̂ = 1/γ̂: fitted for the sensors in ``free``, given for the others."""
    free: tuple[int, ...]
    statistic: float
    """T(β̂)."""
    p_value: float
    """P(χ²(dof − |free|) > T(β̂)): the probability of a statistic this large if the hypothesis holds."""
    standard_error: float
    """The largest standard error of the fitted β̂ (0 if none is fitted)."""
    samples: int
    """The samples after the change the hypothesis places (the window's length if none)."""

    @property
    def kind(self) -> tuple[tuple[int, ...], tuple[bool, ...]]:
        """Which gains it fits, and which of the others it puts at 1."""
        return self.free, tuple(bool(b == 1.0) for j, b in enumerate(self.beta) if j not in self.free)


def gain_hypotheses(
    system: WindowSystem, alpha: float, lower: np.ndarray, upper: np.ndarray, previous: np.ndarray, samples: int
) -> list[GainHypothesis]:
    """The hypotheses with the fewest fitted gains that the window does not reject at level α; none
    if it rejects every one (no constant gains explain it).

    Each sensor's gain is either fitted (least squares; BVLS within [lower, upper] on β), or given:
    its ``previous`` β, or 1 (healthy). With |S| gains fitted, T(β̂) ~ χ²(dof − |S|) if the
    hypothesis holds, so a true hypothesis is rejected with probability α: a gain differs from its
    previous value, or from 1, only if every hypothesis that keeps it is rejected."""
    R, c = system.factor, system.rotated
    m = R.shape[1]
    for size in range(m + 1):
        dof = system.dof - size
        threshold = _chi2_quantile(alpha, dof)
        accepted: list[GainHypothesis] = []
        for free in itertools.combinations(range(m), size):
            index = list(free)
            columns = R[:, index]
            covariance = np.linalg.pinv(columns.T @ columns) if free else np.zeros((0, 0))
            error = float(np.sqrt(np.max(np.diag(covariance)))) if free else 0.0
            recovered = [j for j in range(m) if j not in free and previous[j] != 1.0]
            for back in itertools.product((False, True), repeat=len(recovered)):
                beta = np.array(previous, dtype=float)
                beta[[j for j, b in zip(recovered, back) if b]] = 1.0
                if free:
                    beta[index] = 0.0
                    rhs = c - R @ beta
                    fitted = covariance @ (columns.T @ rhs)
                    beta[index] = fitted
                    if np.any(fitted < lower[index]) or np.any(fitted > upper[index]):
                        if chi2_statistic(system, beta) > threshold:
                            continue  # the box can only make the fit worse
                        if size == 1:
                            fitted = np.clip(fitted, lower[index], upper[index])
                        else:
                            bounds = (lower[index], upper[index])
                            fitted = scipy.optimize.lsq_linear(columns, rhs, bounds=bounds, method="bvls").x
                        beta[index] = fitted
                statistic = chi2_statistic(system, beta)
                if statistic <= threshold:
                    p = float(scipy.special.chdtrc(dof, statistic))
                    accepted.append(GainHypothesis(beta, free, statistic, p, error, samples))
        if accepted:
            return accepted
    return []


class GainDecision(NamedTuple):
    """What the gain test decided at one tick."""

    gamma: np.ndarray
    """γ̂ after the tick (the previous one unless new gains were identified)."""
    verdict: str
    """``consistent``: the window accepts the previous γ̂, which is kept; ``identified``: it rejects
    it and one hypothesis explains the window, with the change ``samples`` samples ago (``samples``
    = N: before the window); ``pending``: it rejects it, but first did so fewer than min_window
    samples ago, too few to tell what changed (γ̂ kept); ``ambiguous``: several hypotheses explain
    it, or the only one does not resolve its gains to ``se_tol`` (γ̂ kept); ``inconsistent``: none
    explains it (γ̂ kept)."""
    statistic: float
    """T of the previous γ̂ on the window over the (1 − α) quantile of χ²(dof) (≤ 1: accepted)."""
    excitation: float
    """se_tol over the largest standard error of a gain on the window (≥ 1: it resolves every gain
    to se_tol)."""
    samples: int
    """The samples since the change the decision places (N: none in the window)."""


def decide_gains(
    window: GainTestWindow,
    y: np.ndarray,
    u: np.ndarray,
    gamma: np.ndarray,
    alpha: float,
    lower: np.ndarray,
    upper: np.ndarray,
    se_tol: float,
    reference: np.ndarray | None = None,
    since: int | None = None,
) -> GainDecision:
    """γ̂ changes only on evidence (docs/three-tank.md, "The gain test").

    Without ``reference`` the window of the last N samples first tests the previous γ̂: if T(1/γ̂)
    is within the (1 − α) quantile of χ²(dof), γ̂ is kept. Otherwise the gains changed, from
    ``reference`` (the γ̂ before the change; default: the previous γ̂), and the hypotheses are:

    - the change is before the window: constant gains over it (``gain_hypotheses``);
    - it is at sample c of the window, L = N − c ≥ min_window samples ago: the known gains before c,
      the hypothesis after it, every offset free to jump at c;
    - only if none of these is accepted (two changes in the window, e.g. a bias step, then a gain):
      the last L samples alone, for L = min_window, min_window + 1, … up to the first L that no
      hypothesis explains, and at most ``since`` (the samples since the window first rejected the
      gains before the change, so that none reaches back across it); the longest one that identifies.

    Nothing is identified until the window has rejected the gains before the change for min_window
    samples (``since``): a change seen in fewer samples is explained as well by hypotheses that place
    it earlier.

    Among the accepted hypotheses with the fewest fitted gains, the one with the largest p-value is
    taken, provided all of them agree on which gains changed (and which returned to 1) and its
    fitted gains have standard errors within ``se_tol``; otherwise the decision is ``ambiguous``.

    y (N, m), u (N, n_u) as in ``window_system``; gamma: the previous γ̂; lower, upper: the box Γ."""
    N = window.window
    full = window_system(window, y, u)
    threshold = _chi2_quantile(alpha, full.dof)
    statistic = chi2_statistic(full, 1.0 / gamma) / threshold
    excitation = se_tol / float(np.max(gain_standard_errors(full)))
    if reference is None:
        if statistic <= 1.0:
            return GainDecision(gamma, "consistent", statistic, excitation, N)
        reference = gamma
    since = 1 if since is None else since
    if since < window.min_window:
        return GainDecision(gamma, "pending", statistic, excitation, N)
    previous, beta_lower, beta_upper = 1.0 / reference, 1.0 / upper, 1.0 / lower
    accepted = gain_hypotheses(full, alpha, beta_lower, beta_upper, previous, N)
    for L in range(window.min_window, N if since < N else window.min_window):
        split = window_system(window, y, u, change=N - L, before=previous)
        accepted += gain_hypotheses(split, alpha, beta_lower, beta_upper, previous, L)
    if accepted:
        fewest = min(len(h.free) for h in accepted)
        accepted = [h for h in accepted if len(h.free) == fewest]
        # The change before the window if that explains it (m fewer unknowns), else the likeliest split.
        before = [h for h in accepted if h.samples == N]
        best = max(before or accepted, key=lambda h: h.p_value)
        if len({h.kind for h in accepted}) > 1 or best.standard_error > se_tol:
            return GainDecision(gamma, "ambiguous", statistic, excitation, N)
        return GainDecision(1.0 / best.beta, "identified", statistic, excitation, best.samples)
    found, explained = None, False
    for L in range(window.min_window, min(N - 1, since) + 1):
        sub = window_system(window, y[N - L :], u[N - L :])
        hypotheses = gain_hypotheses(sub, alpha, beta_lower, beta_upper, previous, L)
        if not hypotheses:
            break
        explained = True
        best = max(hypotheses, key=lambda h: h.p_value)
        if len({h.kind for h in hypotheses}) == 1 and best.standard_error <= se_tol:
            found = best
    if found is not None:
        return GainDecision(1.0 / found.beta, "identified", statistic, excitation, found.samples)
    return GainDecision(gamma, "ambiguous" if explained else "inconsistent", statistic, excitation, N)


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
    design_free = frozenset(
        {"Hz", "window", "x0", "pe_tol", "gain_estimator", "fit_tol", "noise_std", "alpha", "min_window", "se_tol"}
    )

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
        if params.gain_estimator not in ("paper", "model", "test"):
            raise ParameterError(
                "gain_estimator", f'{params.gain_estimator!r}: use "paper" (eq. (53)), "model" or "test"'
            )
        self.aug = SensorFaultModel(model.A, np.hstack([model.B, self.c[:, None]]), model.E, model.C, self.F)
        self.lower, self.upper = np.full(p, design_min), np.full(p, params.gamma_max)
        self.Abar, self.Bbar = self.aug.Abar, self.aug.Bbar
        self._design()
        x0 = model.x_op if params.x0 is None else np.asarray(params.x0, dtype=float)
        if x0.shape != (n,):
            raise ParameterError("x0", f"expected {n} values ({', '.join(model.states)}), got {x0.size}")
        self.x_bar0 = np.concatenate([x0 - self.x_s, np.zeros(self.aug.q)])
        self.model_window = (
            model_window(model.A, self.aug.B, model.E, model.C, params.window)
            if params.gain_estimator == "model"
            else None
        )
        self.gain_test = self._gain_test_window() if params.gain_estimator == "test" else None
        self.reset()

    def _gain_test_window(self) -> GainTestWindow:
        """The whitened model window of ``gain_estimator = "test"``, its parameters checked."""
        params, p = self.params, self.model.p
        if params.noise_std is None:
            raise ParameterError(
                "noise_std", 'gain_estimator = "test" needs the readings\' noise level, one σ per sensor'
            )
        sigma = (
            np.broadcast_to(np.asarray(params.noise_std, dtype=float), (p,))
            if np.ndim(params.noise_std) == 0
            else (np.asarray(params.noise_std, dtype=float))
        )
        if sigma.shape != (p,) or not np.all(sigma > 0):
            raise ParameterError(
                "noise_std", f"expected one positive σ, or {p} (one per sensor), got {params.noise_std}"
            )
        if not 0.0 < params.alpha < 1.0:
            raise ParameterError("alpha", f"a false-alarm probability in (0, 1), got {params.alpha}")
        if not params.se_tol > 0.0:
            raise ParameterError("se_tol", f"must be positive, got {params.se_tol}")
        if params.gamma_max != 1.0:
            raise ParameterError("gamma_max", 'gain_estimator = "test" tests γ = 1: the box Γ must contain it (γ̄ = 1)')
        if not 2 <= params.min_window <= params.window:
            raise ParameterError("min_window", f"must lie in [2, window] = [2, {params.window}]")
        window = gain_test_window(
            self.model.A, self.aug.B, self.model.E, self.model.C, sigma, params.window, params.min_window
        )
        dof = params.min_window * p - window.bases[0].shape[1]
        if dof <= p:
            raise ParameterError(
                "min_window",
                f"{params.min_window} samples leave {dof} equations beyond the model's unknowns, "
                f"not more than the {p} gains: take more",
            )
        return window

    def reset(self) -> None:
        self.gamma = np.ones(self.model.p)  # Algorithm 1/2, initialization step 3: Δ(γ̂) = I
        self.x_hat: np.ndarray | None = None
        self.previous: tuple[np.ndarray, np.ndarray] | None = None  # (y, u) of the previous tick
        # The gain test keeps one sample more: the UIO's state before a sub-window of N samples.
        self.history: deque[_Sample] = deque(maxlen=self.params.window + (self.gain_test is not None))
        self.pe = 0.0
        self.fit = 0.0
        self.decision: GainDecision | None = None
        self.reference: np.ndarray | None = None  # the gain test: γ̂ before the change it is identifying
        self.episode = 0  # the gain test: ticks since it rejected the settled γ̂
        self.unexplained = 0  # the gain test: ticks in a row whose window no identified gains explain

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
        u_bar = np.append(u, 1.0)
        if self.gain_test is not None:
            self._tested_step(y, u_bar)
        else:
            self.history.append(self._observe(y, u_bar, self.gamma))  # with γ̂(t−1)
            if len(self.history) == self.params.window:
                if self.model_window is not None:
                    self.gamma = self._estimate_gamma_on_the_model()
                else:
                    self.gamma = self._estimate_gamma()
        n = self.model.n
        assert self.x_hat is not None
        x_p, b = self.x_hat[:n], self.x_hat[n:]
        z = float(self.Hz @ (self.model.C @ x_p))  # eq. (6)
        diagnostics = {f"gamma_{name}": float(g) for name, g in zip(self.model.outputs, self.gamma)}
        diagnostics |= {name: float(v) for name, v in zip(self._bias_names(self.aug.q), b)}
        diagnostics |= {"zhat": z, "pe": self.pe, "fit": min(self.fit, 999.0)}
        return Estimate(x_p + self.x_s, diagnostics)

    def _observe(self, y: np.ndarray, u_bar: np.ndarray, gamma: np.ndarray, coast: bool = False) -> _Sample:
        """One step of the UIO (10) with T, Q and L at ``gamma`` (Algorithm 1 step 5, Algorithm 2
        step 4): x̂(t) = T x̄(t) + L (y(t−1) − C̄ x̂(t−1)) + Q y(t), x̄(t) = Ā x̂(t−1) + B̄ u(t−1).
        A reading that did not arrive is replaced by its prediction C̄ x̄(t); with ``coast`` all
        are, and x̂(t) is the model's prediction x̄(t) (eq. (11): T + Q C̄ = I)."""
        Q, T = uio_matrices(self.aug, gamma, form=self.form)
        Cbar = self.aug.Cbar(gamma)
        if self.x_hat is None or self.previous is None:  # t = 0: the UIO's own reconstruction from y(0) about x̂₀
            prior = self.x_bar0
            x_next = T @ prior
        else:
            y_prev, u_prev = self.previous
            prior = self.Abar @ self.x_hat + self.Bbar @ u_prev
            x_next = T @ prior + self.gain(gamma) @ (y_prev - Cbar @ self.x_hat)  # eq. (10)
        used = np.where(np.isnan(y) | coast, Cbar @ prior, y)
        self.x_hat = x_next + Q @ used
        self.previous = (used, u_bar)
        n = self.model.n
        return _Sample(used, self.x_hat[:n].copy(), self.x_hat[n:].copy(), y, u_bar)

    def _tested_step(self, y: np.ndarray, u_bar: np.ndarray) -> None:
        """One tick with ``gain_estimator = "test"``. The gain test runs first, on the window up to
        this tick (``decide_gains``). If it identifies the gains, with a change L samples ago, the UIO
        runs again over those samples with them, from its estimate before them. If it rejects γ̂
        without identifying new gains (a change under way), the UIO does not use this tick's readings,
        since the data reject its sensor model (``_observe`` with ``coast``); they are used by the
        replay once the gains are identified. After N ticks without identification the window no
        longer holds the change, and the UIO goes on with γ̂ as it is."""
        self.history.append(_Sample(y, np.zeros(self.model.n), np.zeros(self.aug.q), y, u_bar))
        if len(self.history) < self.params.window:
            self.history[-1] = self._observe(y, u_bar, self.gamma)
            return
        decision = self._test_gamma()
        self.unexplained = 0 if decision.verdict in ("consistent", "identified") else self.unexplained + 1
        if decision.verdict == "identified":
            self.gamma = decision.gamma
            start = len(self.history) - decision.samples
            if start >= 1:
                before = self.history[start - 1]
                self.x_hat, self.previous = np.concatenate([before.x_p, before.b]), (before.y, before.u)
            else:
                self.x_hat, self.previous = None, None
            for i in range(start, len(self.history)):
                self.history[i] = self._observe(self.history[i].measured, self.history[i].u, self.gamma)
        else:
            coast = 0 < self.unexplained <= self.params.window
            self.history[-1] = self._observe(y, u_bar, self.gamma, coast)

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
        assert self.model_window is not None
        ys, us = (np.array([getattr(sample, field) for sample in self.history]) for field in ("measured", "u"))
        gamma, sv, self.fit = window_gains(self.model_window, ys, us, self.lower, self.upper)
        self.pe = self._excitation(sv, self.model.p)
        return gamma if self.pe > 0.0 and self.fit <= self.params.fit_tol else self.gamma

    def _test_gamma(self) -> GainDecision:
        """The χ² test of the last N samples (``decide_gains``): γ̂ is kept unless they reject it."""
        assert self.gain_test is not None
        window = list(self.history)[-self.params.window :]
        ys, us = (np.array([getattr(sample, field) for sample in window]) for field in ("measured", "u"))
        self.decision = decide_gains(
            self.gain_test,
            ys,
            us,
            self.gamma,
            self.params.alpha,
            self.lower,
            self.upper,
            self.params.se_tol,
            self.reference,
            1 if self.reference is None else self.episode + 1,  # samples since the episode began
        )
        if self.reference is None and self.decision.verdict != "consistent":
            self.reference, self.episode = self.gamma, 0  # an episode begins: the gains before the change
        self.episode += 1
        if self.episode >= self.params.window:
            self.reference = None  # the change is older than the window: γ̂ is tested as it is from now
        # se_tol over the largest standard error: ≥ 1 when the window resolves every gain; published
        # up to 2, the channel's declared range (a well-excited window reads 2, not its exact margin).
        self.pe = min(self.decision.excitation, 2.0) if self.decision.excitation >= 1.0 else 0.0
        self.fit = self.decision.statistic
        return self.decision

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
                "persistence of excitation σ_min/σ_max of the window's regressor (condition (55); gain test: se_tol"
                " over the largest standard error of a gain, up to 2); 0: not met",
                2.0,
                1e-9,
                DiagnosticKind.EXCITATION,
            ),
            Diagnostic(
                "fit",
                "",
                "relative residual of the window's equations for γ̂ ((53), or the model window; gain test: the χ²"
                " statistic of γ̂ over its threshold, ≤ 1: accepted)",
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
            design: LpvDesign = self._solve(lpv_uio_design)
            self.design, self.G_vertices, self.Y_vertices = design, design.G, design.Y

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
            design: LftDesign = self._solve(lft_uio_design, multiplier=self.params.multiplier)
            self.design, self.L = design, design.L

    def gain(self, gamma: np.ndarray) -> np.ndarray:
        return self.L

    def design_params(self) -> dict[str, Any]:
        return {"L": self.L.tolist()}
