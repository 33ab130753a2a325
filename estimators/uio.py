"""The classic continuous-time unknown input observer (UIO) and its residual for fault detection.

Course notes "Estimation for control — Practical Assignment 9", eq. (1)–(16). For the plant

    ẋ = A x + B u + E d,  y = C x                                                  (1)

with an unknown input d of known direction E, the observer

    ż = F z + T B u + K y,  x̂ = z + H y                                            (2)

with

    F = T A − K1 C,  K2 = F H,  K = K1 + K2,  T = I − H C,  H = E (CE)⁺          (8)

has the error dynamics ė = F e (6), whatever d is: (7) makes every term in x, u and d vanish.
(CE)⁺ is the LEFT pseudo-inverse, (CE)⁺ CE = I (the notes' eq. (8) states the right inverse; see
docs/uio.md), so that H C E = E and T E = 0. Existence: rank(CE) = rank(E) (H exists) and
(TA, C) detectable (a K1 with F Hurwitz exists; observable for an arbitrary spectrum).

Fault detection uses the residual r = y − C x̂ (10): a sensor fault y = C x + f_s gives
r = C e + f_s, an actuator fault ẋ = … + B f_a gives ė = F e + T B f_a (12), so r ≠ 0 in both
cases, while the unknown input d leaves r → 0. The published ``alarm`` is 1 when |r| > ``threshold``
at a sample from ``arm_time`` on, else 0 (the notes give no decision rule; this is the plain
threshold test on |r|). Before ``arm_time`` the residual still carries the initial error
e(t) = e^{Ft} e(0), which no threshold can tell from a fault; the default arm_time = 5/|Re λ|
of F's slowest eigenvalue λ lets e^{Ft} decay to e^{-5} < 1 % of e(0) (for a diagonalizable F).
The default threshold 0.05 (in the outputs' units) comes from the worked example (13) with the
design σ(F) = {−1, −2, −3} (docs/uio.md): 100 times the healthy residual at 8–10 s and a tenth of
the first-sample response (I − C H) f_s to the sensor fault f_s = 0.5; set it for another plant
from its noise level and the smallest fault to detect.

A plant output y = C x + D u is handled by feeding y − D u to the observer.

Sampling. The estimator sees y and u only at the sample instants t_k and integrates (2) exactly
over each interval, which (2) being linear is one matrix exponential computed at design time. At
tick k it advances z from t_{k−1} to t_k, then returns x̂_k = z_k + H y_k:

- u is held at u_{k−1} over [t_{k−1}, t_k), as the plant's actuators hold it (the runner applies
  each command for one sample time): exact;
- y is, by default (``y_hold = "linear"``), interpolated linearly between y_{k−1} and y_k, which
  is causal here since y_k has arrived when z_k is computed. The result is exact for piecewise-
  linear y and leaves an O(τ²) error for the true, smooth y(t); with ``y_hold = "zero-order"``
  y is held at y_{k−1} (exact for piecewise-constant y and u: the ZOH discretization of
  (F, [T B, K])), which leaves an O(τ) error. On the notes' example at τ = 0.01 s, the residual
  floor without faults is about 1e-5 (linear) against 4e-3 (zero-order); docs/uio.md has the
  figures.

Missing readings (NaN) are replaced by the last reading received on that output.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from estimators.base import Estimate, Estimator, ParameterError, initial_state
from estimators.batched import BatchEstimate, DeviationBatch, mv
from estimators.design import AssumptionError, check_spectrum, observer_gain
from estimators.diagnostics import Diagnostic, DiagnosticKind
from estimators.model import LinearModel


class UIOConditionError(AssumptionError):
    """An existence condition of the UIO fails (``condition`` names it: "rank" or "detectability")."""

    def __init__(self, condition: str, message: str) -> None:
        super().__init__(message)
        self.condition = condition


@dataclass(frozen=True)
class UIODesign:
    """The matrices of observer (2), from eq. (8)."""

    H: np.ndarray
    T: np.ndarray
    F: np.ndarray
    K1: np.ndarray
    K2: np.ndarray

    @property
    def K(self) -> np.ndarray:
        """K = K1 + K2 (eq. (4))."""
        return self.K1 + self.K2


def _tol(M: np.ndarray) -> float:
    return 1e-9 * max(1.0, float(np.abs(M).max()) if M.size else 1.0)


def uio_gains(C: np.ndarray, E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """H = E (CE)⁺ and T = I − H C of eq. (8), after checking rank(CE) = rank(E).

    (CE)⁺ is the Moore–Penrose pseudo-inverse: the left inverse ((CE)ᵀCE)⁻¹(CE)ᵀ when CE has full
    column rank, and in general the one that makes H C E = E hold whenever rank(CE) = rank(E).
    Raises UIOConditionError("rank") otherwise.
    """
    C = np.asarray(C, dtype=float)
    E = np.asarray(E, dtype=float)
    CE = C @ E
    rank_E = np.linalg.matrix_rank(E, tol=_tol(E))
    rank_CE = np.linalg.matrix_rank(CE, tol=_tol(CE))
    if rank_CE != rank_E:
        raise UIOConditionError(
            "rank",
            (
                f"rank(CE) = {rank_CE} < rank(E) = {rank_E}: no H with H C E = E exists (eq. (8) needs rank(CE) = "
                "rank(E)); "
                "some direction of the unknown input is invisible in the outputs' first derivative. Measure a state "
                "that the unknown input drives directly, or model fewer unknown inputs (columns of E)"
            ),
        )
    H = E @ np.linalg.pinv(CE)
    T = np.eye(E.shape[0]) - H @ C
    if not np.allclose(H @ CE, E, atol=1e-9 * max(1.0, np.abs(E).max())):
        raise UIOConditionError("rank", "H C E = E does not hold numerically: CE is too ill-conditioned")
    return H, T


def unobservable_modes(A: np.ndarray, C: np.ndarray, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """(Q, modes): an orthonormal Q = [Q_o, Q_u] whose last columns span the unobservable subspace
    of (A, C), and the eigenvalues of A restricted to that subspace (the modes no output
    injection can move). In the coordinates Qᵀ x the pair is block triangular:
    QᵀAQ = [[A_oo, 0], [A_uo, A_uu]], C Q = [C_o, 0]."""
    A = np.asarray(A, dtype=float)
    C = np.asarray(C, dtype=float)
    n = A.shape[0]
    blocks, M = [], C
    for _ in range(n):
        blocks.append(M)
        M = M @ A
    O = np.vstack(blocks)
    _, sv, Vt = np.linalg.svd(O)
    rank = int(np.sum(sv > tol * max(1.0, sv[0] if sv.size else 1.0)))
    Q = Vt.T
    Qu = Q[:, rank:]
    return Q, np.linalg.eigvals(Qu.T @ A @ Qu) if Qu.shape[1] else np.zeros(0, dtype=complex)


def check_detectable(TA: np.ndarray, C: np.ndarray) -> np.ndarray:
    """The unobservable modes of (TA, C); raises UIOConditionError("detectability") if one has
    Re λ ≥ 0, since then no K1 makes F = TA − K1 C Hurwitz."""
    _, modes = unobservable_modes(TA, C)
    bad = [lam for lam in modes if lam.real >= -1e-9]
    if bad:
        listed = ", ".join(
            f"{complex(lam).real:.6g}" + (f"{complex(lam).imag:+.6g}j" if abs(lam.imag) > 1e-12 else "") for lam in bad
        )
        raise UIOConditionError(
            "detectability",
            (
                f"(TA, C) is not detectable: the mode(s) {listed} of TA are unobservable through C and not stable, so "
                "F = TA − K1 C keeps them for every K1 and cannot be Hurwitz (eq. (8)). They are the unstable "
                "invariant "
                "zeros of (A, E, C): the unknown input can drive the state along them without any trace in y. Add a "
                "sensor or model fewer unknown inputs"
            ),
        )
    return modes


def uio_design(
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    E: np.ndarray,
    poles: ArrayLike | None = None,
    K1: ArrayLike | None = None,
) -> UIODesign:
    """The unknown input observer (2) of the course notes, eq. (8).

    1. H = E (CE)⁺ and T = I − H C (requires rank(CE) = rank(E));
    2. (TA, C) must be detectable;
    3. K1 is given, or placed so that σ(F) = ``poles`` with F = T A − K1 C (continuous time:
       negative real parts). Modes of TA unobservable through C are eigenvalues of F whatever K1
       (detectable but not observable): ``poles`` must then either list them too (n poles) or
       give only the n − n_u placeable ones;
    4. K2 = F H.

    Raises UIOConditionError for a failed existence condition and ValueError for bad poles or K1.
    """
    A = np.asarray(A, dtype=float)
    C = np.asarray(C, dtype=float)
    E = np.asarray(E, dtype=float)
    n = A.shape[0]
    if E.ndim != 2 or E.shape[0] != n or E.shape[1] == 0:
        raise ValueError(f"E must have {n} rows and at least one column, got shape {E.shape}")
    H, T = uio_gains(C, E)
    TA = T @ A
    modes = check_detectable(TA, C)
    if (poles is None) == (K1 is None):
        raise ValueError("give exactly one of poles (the spectrum of F) and K1")
    if K1 is not None:
        K1 = np.asarray(K1, dtype=float)
        if K1.shape != (n, C.shape[0]):
            raise ValueError(f"K1 must have shape ({n}, {C.shape[0]}), got {K1.shape}")
    else:
        K1 = _place(TA, C, np.asarray(poles), modes)
    F = TA - K1 @ C
    if np.max(np.linalg.eigvals(F).real) >= 0:
        raise ValueError(f"F = TA − K1 C is not Hurwitz: eigenvalues {np.round(np.linalg.eigvals(F), 6).tolist()}")
    return UIODesign(H, T, F, K1, F @ H)


def _place(TA: np.ndarray, C: np.ndarray, poles: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """K1 with σ(TA − K1 C) = poles, placing only the observable part when some modes are fixed."""
    n = TA.shape[0]
    if np.any(np.real(poles) >= 0):
        raise ValueError(f"{np.asarray(poles).tolist()}: every pole of F needs a negative real part (F Hurwitz)")
    if fixed.size == 0:
        return observer_gain(TA, C, poles)
    listed = np.sort_complex(np.round(fixed.astype(complex), 6)).tolist()
    if poles.size == n:
        rest = list(poles.astype(complex))
        for lam in fixed:
            match = min(range(len(rest)), key=lambda i: abs(rest[i] - lam)) if rest else None
            if match is None or abs(rest[match] - lam) > 1e-6 * max(1.0, abs(lam)):
                raise ValueError(
                    f"(TA, C) is detectable but not observable: F keeps the modes {listed} of TA whatever K1; "
                    f"list them among the poles, or give only the {n - fixed.size} placeable poles"
                )
            rest.pop(match)
        poles = np.real_if_close(np.array(rest))
    elif poles.size != n - fixed.size:
        raise ValueError(
            f"need {n} poles (including the fixed modes {listed}) or the {n - fixed.size} placeable ones, got "
            f"{poles.size}"
        )
    Q, _ = unobservable_modes(TA, C)
    k = n - fixed.size
    Qo = Q[:, :k]
    L = observer_gain(Qo.T @ TA @ Qo, C @ Qo, poles)
    K1 = Qo @ L
    check_spectrum(TA - K1 @ C, np.concatenate([np.asarray(poles, dtype=complex), fixed]), tol=1e-6)
    return K1


@dataclass(frozen=True)
class UIOParams:
    poles: tuple[float, ...] | None = None
    """Spectrum of F = T A − K1 C (negative reals), when ``K1`` is not given."""
    K1: tuple[tuple[float, ...], ...] | None = None
    """The gain K1 (n rows of p numbers), e.g. eq. (15); or give ``poles``."""
    E: tuple[tuple[float, ...], ...] | None = None
    """Unknown-input matrix (n rows, one column per unknown input); None: the model's E."""
    x0: tuple[float, ...] | None = None
    """Initial estimate x̂(0) (absolute; z(0) = x̂(0) − H y(0)); None: the operating point."""
    y_hold: str = "linear"
    """How y is taken between samples when integrating (2): "linear" (interpolated between y_{k−1}
    and y_k, O(τ²) error) or "zero-order" (held at y_{k−1}, O(τ) error)."""
    threshold: float = 0.05
    """The alarm is raised when |r| exceeds it (outputs' units)."""
    arm_time: float | None = None
    """Time [s] from which the alarm may be raised; None: 5/|Re λ| for F's slowest eigenvalue λ."""


RESIDUAL = Diagnostic("r_{}", "", "residual r = y − C x̂ ({}), eq. (10)", 1e3, 1e-6, DiagnosticKind.RESIDUAL)
RESIDUAL_NORM = Diagnostic("residual_norm", "", "|r| = |y − C x̂|, eq. (10)", 1e3, 1e-6, DiagnosticKind.RESIDUAL_NORM)
ALARM = Diagnostic("alarm", "", "1: |r| > threshold (from arm_time on), else 0", 1.0, 1.0, DiagnosticKind.ALARM)
"""The UIO's diagnostics: the residual per output, its norm, the alarm."""


class UnknownInputObserver(Estimator):
    """Observer (2) with the design (8), integrated exactly between samples; publishes the
    residual r = y − C x̂ (10) per output and its norm."""

    kind = "uio"
    Params = UIOParams
    continuous = True

    def __init__(self, model: LinearModel, params: UIOParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        n = model.n
        if params.E is not None:
            E = np.array(params.E, dtype=float)
            if E.ndim != 2 or E.shape[0] != n:
                raise ParameterError(
                    "E",
                    f"expected a matrix with {n} rows (one per state: {', '.join(model.states)}), got shape {E.shape}",
                )
        elif model.E.shape[1]:
            E = model.E
        else:
            raise ParameterError(
                "E",
                "the model has no unknown input (E has no column): give params.E, or E and "
                "disturbances in [plant.state_space] (or disturbance actuators in the MJCF plant)",
            )
        try:
            self.design = uio_design(model.A, model.B, model.C, E, params.poles, params.K1)
        except UIOConditionError as error:
            raise ParameterError(
                "E" if error.condition == "rank" else "model", f"{error} (course notes, eq. (8))"
            ) from None
        except ValueError as error:
            raise ParameterError("K1" if params.K1 is not None else "poles", str(error)) from None
        if params.y_hold not in ("linear", "zero-order"):
            raise ParameterError("y_hold", f'expected "linear" or "zero-order", got {params.y_hold!r}')
        if not (math.isfinite(params.threshold) and params.threshold > 0):
            raise ParameterError(
                "threshold", f"expected a positive number (the alarm limit on |r|), got {params.threshold}"
            )
        if params.arm_time is not None and not (math.isfinite(params.arm_time) and params.arm_time >= 0):
            raise ParameterError("arm_time", f"expected a time >= 0 in seconds, got {params.arm_time}")
        slowest = float(np.max(np.linalg.eigvals(self.design.F).real))
        self.arm_time = 5.0 / -slowest if params.arm_time is None else params.arm_time
        self.ticks = 0
        self.E = E
        self.Phi, self.Gu, self.Gy0, self.Gy1 = discretize(
            self.design, model.B, self.sample_time, params.y_hold == "linear"
        )
        self.x_init = initial_state(model, params.x0)
        self.z: np.ndarray | None = None
        self.y_prev = model.C @ self.x_init  # also what a missing reading is replaced by until one arrives
        self.u_prev = np.zeros(model.m)

    @classmethod
    def diagnostic_channels(cls, states: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        return [*RESIDUAL.over(outputs), RESIDUAL_NORM, ALARM]

    def _step(self, dy: np.ndarray, du: np.ndarray) -> Estimate:
        model, d = self.model, self.design
        y = dy - model.D @ du
        y = np.where(np.isnan(y), self.y_prev, y)  # a missing reading keeps the last one received
        if self.z is None:
            z = self.x_init - d.H @ y  # so that x̂(0) = x0
        else:  # eq. (2) from t_{k−1} to t_k: u held, y interpolated (or held)
            z = self.Phi @ self.z + self.Gu @ self.u_prev + self.Gy0 @ self.y_prev + self.Gy1 @ y
        x_hat = z + d.H @ y  # eq. (2)
        r = y - model.C @ x_hat  # eq. (10)
        self.z, self.y_prev, self.u_prev = z, y, du
        diagnostics = RESIDUAL.values(model.outputs, r)
        diagnostics[RESIDUAL_NORM.name] = norm = float(np.linalg.norm(r))
        armed = self.ticks * self.sample_time >= self.arm_time - 1e-9 * self.sample_time
        diagnostics[ALARM.name] = float(armed and norm > self.params.threshold)
        self.ticks += 1
        return Estimate(x_hat, diagnostics)

    @classmethod
    def batched(cls, instances: Sequence[UnknownInputObserver]) -> _UIOBatch:
        return _UIOBatch(instances)


class _UIOBatch(DeviationBatch):
    """K observers (2) of one design: z (K, n) integrated in the stacked kernels; the residual's
    norm per run as ``np.linalg.norm`` takes it (a dot product)."""

    def __init__(self, instances: Sequence[UnknownInputObserver]) -> None:
        super().__init__(instances)
        first = self.first = instances[0]
        self.z: np.ndarray | None = None
        self.y_prev = np.stack([e.y_prev for e in instances])
        self.u_prev = np.stack([e.u_prev for e in instances])
        self.ticks = first.ticks

    def _step(self, dy: np.ndarray, du: np.ndarray) -> BatchEstimate:
        model, first, d = self.model, self.first, self.first.design
        y = dy - mv(model.D, du)
        y = np.where(np.isnan(y), self.y_prev, y)
        if self.z is None:
            z = first.x_init - mv(d.H, y)
        else:
            z = mv(first.Phi, self.z) + mv(first.Gu, self.u_prev) + mv(first.Gy0, self.y_prev) + mv(first.Gy1, y)
        x_hat = z + mv(d.H, y)
        r = y - mv(model.C, x_hat)
        self.z, self.y_prev, self.u_prev = z, y, du
        diagnostics = {RESIDUAL.named(name): r[:, i] for i, name in enumerate(model.outputs)}
        norm = np.array([float(np.linalg.norm(row)) for row in r])
        diagnostics[RESIDUAL_NORM.name] = norm
        armed = self.ticks * first.sample_time >= first.arm_time - 1e-9 * first.sample_time
        diagnostics[ALARM.name] = (armed & (norm > first.params.threshold)).astype(float)
        self.ticks += 1
        return BatchEstimate(x_hat, diagnostics)


def discretize(design: UIODesign, B: np.ndarray, tau: float, linear_y: bool = True) -> tuple[np.ndarray, ...]:
    """(Φ, Γ_u, Γ_0, Γ_1) with z(τ) = Φ z(0) + Γ_u u + Γ_0 y(0) + Γ_1 y(τ), the exact solution of
    ż = F z + T B u + K y over [0, τ] with u constant and y linear in t (``linear_y``) or constant
    at y(0) (then Γ_1 = 0: the zero-order hold of (F, [T B, K])).

    One matrix exponential (Van Loan): with w = (u, y, ẏ) and ẏ = (y(τ) − y(0))/τ constant,
    d/dt (z, w) = [[F, [TB, K, 0]], [0, N]] (z, w), N shifting ẏ into y; if
    exp(·τ) = [[Φ, Γ_u, Γ_a, Γ_b], …], then Γ_0 = Γ_a − Γ_b/τ and Γ_1 = Γ_b/τ.
    """
    F, K = design.F, design.K
    n, m, p = F.shape[0], B.shape[1], K.shape[1]
    size = n + m + 2 * p
    M = np.zeros((size, size))
    M[:n, :n] = F
    M[:n, n : n + m] = design.T @ B
    M[:n, n + m : n + m + p] = K
    M[n + m : n + m + p, n + m + p :] = np.eye(p)
    X = scipy.linalg.expm(M * tau)
    Phi, Gu, Ga, Gb = X[:n, :n], X[:n, n : n + m], X[:n, n + m : n + m + p], X[:n, n + m + p :]
    if linear_y:
        return Phi, Gu, Ga - Gb / tau, Gb / tau
    return Phi, Gu, Ga, np.zeros_like(Ga)
