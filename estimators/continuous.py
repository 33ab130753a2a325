"""The continuous-time adaptive pseudo-inverse observer of Cristofaro & Zaccarian, IEEE CDC 2016.

For ẋ = A x + B u, y = C x + φ with C = Y H, rk C = q < p:

    Z_Γ = (Yᵀ G_Γ Y)⁻¹ Yᵀ G_Γ,  G_Γ = diag(Γ)                                   (5)
    dx̂/dt = A x̂ + B u + L (Z_Γ y − H x̂)                                       (6)
    dΓ/dt = −κ_φ |det(Yᵀ G_Γ Y)| ∇_Γ|Z_Γ y − H x̂|²ᵀ + κ_Γ (1 − |Γ|²) Γ          (7)
    ∇_Γ|Z_Γ y − ẑ|²ᵀ = 2 diag(y − Y Z_Γ y) Y (Yᵀ G_Γ Y)⁻¹ (Z_Γ y − ẑ)           (8)

The estimator sees y only at the sample instants; it holds y (and u) between ticks and integrates
(6)–(7) (``estimators.continuous_ode.ObserverODE``, with its Jacobian in closed form) by an
L-stable fourth-order Rosenbrock method under error control (``estimators.rosenbrock.integrate``):
once a fault is present the adaptation (7) is stiff (its rate grows with κ and with the fault),
which would hold an explicit method to steps far below the sample time. The paper gives Y and H
explicitly (not orthonormal); they are parameters here, since the weights Γ it converges to depend
on that choice.

The runs of a batch are integrated together (``ContinuousAdaptiveObserver.batched``), each run with
its own steps and bit for bit as alone.
"""

from __future__ import annotations

import pickle
from collections.abc import Hashable, Sequence
from dataclasses import dataclass

import numpy as np

from estimators.base import Diagnostic, DiagnosticKind, Estimate, Estimator, ParameterError, initial_state
from estimators.batched import BatchEstimate, DeviationBatch, mv
from estimators.continuous_ode import ObserverODE, ObserverODERuns
from estimators.design import AssumptionError, check_assumption1, output_factorization
from estimators.model import LinearModel
from estimators.rosenbrock import integrate, integrate_runs


def pseudoinverse(Y: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """Z_Γ of eq. (5), shape (q, p)."""
    weighted = Y.T * gamma
    return np.linalg.solve(weighted @ Y, weighted)


def gradient(Y: np.ndarray, gamma: np.ndarray, y: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
    """∇_Γ |Z_Γ y − ẑ|² in the closed form of eq. (8) (Lemma 1), shape (p,)."""
    weighted = Y.T * gamma
    R = weighted @ Y
    Zy = np.linalg.solve(R, weighted @ y)
    return 2.0 * (y - Y @ Zy) * (Y @ np.linalg.solve(R, Zy - z_hat))


def vector_field(
    x_hat: np.ndarray,
    gamma: np.ndarray,
    y: np.ndarray,
    Bu: np.ndarray,
    A: np.ndarray,
    H: np.ndarray,
    L: np.ndarray,
    Y: np.ndarray,
    kappa_phi: float,
    kappa_gamma: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(dx̂/dt, dΓ/dt) of eq. (6)–(7) with y and u frozen (B u passed in as ``Bu``)."""
    weighted = Y.T * gamma
    R = weighted @ Y
    R_inv = np.linalg.inv(R)
    Zy = R_inv @ (weighted @ y)
    innovation = Zy - H @ x_hat
    dx = A @ x_hat + Bu + L @ innovation
    grad = 2.0 * (y - Y @ Zy) * (Y @ (R_inv @ innovation))
    dgamma = -kappa_phi * abs(np.linalg.det(R)) * grad + kappa_gamma * (1.0 - gamma @ gamma) * gamma
    return dx, dgamma


BATCH_FROM = 6
"""The fewest runs stepped by the K-run step: its NumPy calls cost about 800 µs a tick whatever K
(each a few elements where the one-run step has Python floats), plus 30 µs a run, against about
215 µs a run alone (2 vCPUs, 2026-11-29, ``bench/estimator_step.py``); below 6 runs it would cost more."""


@dataclass(frozen=True)
class ContinuousAdaptiveParams:
    gain: tuple[tuple[float, ...], ...] | None = None
    """Observer gain L (n × q rows), e.g. L1 or L2 of eq. (20); or give ``poles``."""
    poles: tuple[float, ...] | None = None
    """Spectrum of A − L H (negative real parts) when ``gain`` is not given."""
    Y: tuple[tuple[float, ...], ...] | None = None
    """The factor Y of C = Y H (p × q rows), as in Sec. V; None: the orthonormal factorization of C."""
    kappa: float = 1.0
    """Learning rate κ_φ of eq. (7); 0 turns adaptation off (the paper's "no allocation")."""
    kappa_gamma: float | None = None
    """Rate κ_Γ of the norm-keeping term of eq. (7); None: equal to ``kappa`` (the paper's choice)."""
    gamma0: tuple[float, ...] | None = None
    """Initial weights Γ(0); None: 𝟙/√p (Sec. V)."""
    rtol: float = 1e-4
    """Relative error tolerance of the integration between samples."""
    atol: float = 1e-6
    """Absolute error tolerance of the integration between samples."""
    min_det: float = 1e-12
    """|det(Yᵀ G_Γ Y)| below which Z_Γ is deemed undefined: Γ is then held (Remark 1)."""
    x0: tuple[float, ...] | None = None
    """Initial estimate x̂(0) (absolute); None: the operating point."""


class ContinuousAdaptiveObserver(Estimator):
    """Observer (6) with the adaptive weighted pseudo-inverse (5) and adaptation law (7)–(8).

    Diagnostics each tick: the weights Γ and the injected term L (Z_Γ y − H x̂).
    """

    kind = "adaptive-ct"
    Params = ContinuousAdaptiveParams
    continuous = True

    def __init__(self, model: LinearModel, params: ContinuousAdaptiveParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        try:
            check_assumption1(model.A, model.C, discrete=False)
        except AssumptionError as error:
            raise ParameterError("model", f"{error} (CDC 2016)") from None
        n, p = model.n, model.p
        if params.Y is None:
            self.Y, self.H = output_factorization(model.C)
        else:
            self.Y = np.array(params.Y, dtype=float)
            if self.Y.ndim != 2 or self.Y.shape[0] != p or np.linalg.matrix_rank(self.Y) != self.Y.shape[1]:
                raise ParameterError("Y", f"expected a full-column-rank matrix with {p} rows")
            self.H = np.linalg.lstsq(self.Y, model.C, rcond=None)[0]
            if not np.allclose(self.Y @ self.H, model.C, atol=1e-9 * max(1.0, np.abs(model.C).max())):
                raise ParameterError("Y", "C = Y H has no solution H: the columns of Y must span the columns of C")
        q = self.Y.shape[1]
        if params.gain is not None and params.poles is None:
            self.L = np.array(params.gain, dtype=float)
            if self.L.shape != (n, q):
                raise ParameterError("gain", f"expected L of shape ({n}, {q}), got {self.L.shape}")
        elif params.poles is not None and params.gain is None:
            if np.any(np.real(params.poles) >= 0):
                raise ParameterError("poles", f"{list(params.poles)}: every pole needs a negative real part")
            from estimators.design import observer_gain

            try:
                self.L = observer_gain(model.A, self.H, params.poles)
            except ValueError as error:
                raise ParameterError("poles", str(error)) from None
        else:
            raise ParameterError("gain", "give exactly one of gain (the matrix L) and poles")
        if np.max(np.linalg.eigvals(model.A - self.L @ self.H).real) >= 0:
            raise ParameterError("gain", "A − L H is not Hurwitz (Assumption 1)")
        if params.kappa < 0 or (params.kappa_gamma is not None and params.kappa_gamma < 0):
            raise ParameterError("kappa", "learning rates must be non-negative")
        if not (params.rtol > 0 and params.atol > 0):
            raise ParameterError("rtol", "the integration tolerances must be positive")
        self.kappa_phi = params.kappa
        self.kappa_gamma = params.kappa if params.kappa_gamma is None else params.kappa_gamma
        self.gamma = np.full(p, 1.0 / np.sqrt(p)) if params.gamma0 is None else np.array(params.gamma0, dtype=float)
        if self.gamma.shape != (p,):
            raise ParameterError("gamma0", f"expected {p} weights")
        self._check_det(self.gamma, "gamma0")
        self.x_hat = initial_state(model, params.x0)
        self.ode = ObserverODE(model.A, model.B, self.H, self.L, self.Y, self.kappa_phi, self.kappa_gamma)
        self.open_loop = ObserverODE(model.A, model.B, self.H, np.zeros_like(self.L), self.Y, 0.0, 0.0)
        self.h = self.sample_time  # the step size carries over from sample to sample
        self.size = np.abs(np.concatenate([self.x_hat, self.gamma]))  # the largest |x̂_i|, |Γ_j| so far
        self.gamma_names = [f"gamma_{o}" for o in model.outputs]
        self.injection_names = [f"inj_{s}" for s in model.states]

    def _check_det(self, gamma: np.ndarray, where: str) -> None:
        if abs(np.linalg.det((self.Y.T * gamma) @ self.Y)) < self.params.min_det:
            raise ParameterError(where, "Yᵀ diag(Γ) Y is singular: Z_Γ of eq. (5) is undefined")

    @classmethod
    def diagnostic_channels(cls, states: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        return [
            *(
                Diagnostic(
                    f"gamma_{o}", "", f"pseudo-inverse weight Γ ({o}), eq. (7)", 1e3, 1e-6, DiagnosticKind.WEIGHT, o
                )
                for o in outputs
            ),
            *(
                Diagnostic(
                    f"inj_{s}",
                    "",
                    f"injected term L (Z_Γ y − H x̂) ({s}), eq. (6)",
                    1e6,
                    1e-6,
                    DiagnosticKind.INJECTION,
                    s,
                )
                for s in states
            ),
        ]

    def _step(self, dy: np.ndarray, du: np.ndarray) -> Estimate:
        n, x_k, gamma_k, p = self.model.n, self.x_hat, self.gamma, self.params
        finite = np.isfinite(dy).all()  # then without nan_to_num, which costs more than the check
        missing = not finite and np.isnan(dy).any()  # then integrate the observer open loop, weights frozen
        ode = self.open_loop if missing else self.ode
        ode.hold(dy if finite else np.nan_to_num(dy), du)
        w = np.concatenate([x_k, gamma_k])
        f, J = ode.linearized(w)
        injected = np.zeros(n) if missing else f[:n] - self.model.A.dot(x_k) - ode.Bu  # L (Z_Γ y − H x̂) of (6)
        w, self.h = integrate(ode, w, (f, J), self.sample_time, self.h, p.rtol, p.atol, self.size)
        self.x_hat = w[:n]
        if abs(self.ode.weight_det(w[n:])) >= p.min_det:
            self.gamma = w[n:]  # else hold Γ: Z_Γ would be undefined (the reset of Remark 1 is not attempted)
        diagnostics = dict(zip(self.gamma_names, gamma_k.tolist())) | dict(zip(self.injection_names, injected.tolist()))
        return Estimate(x_k, diagnostics)

    def bias_effect(self, diagnostics: dict[str, float], phi: np.ndarray) -> np.ndarray:
        """h_Γ = Z_Γ φ (Sec. IV), the part of the injection due to the fault."""
        gamma = np.array([diagnostics[f"gamma_{o}"] for o in self.model.outputs])
        return pseudoinverse(self.Y, gamma) @ phi

    def joint_batch_key(self) -> Hashable:
        """Observers on one model, sampling, factor Y (so H) and integration settings step together
        whatever their gain L and learning rates (``ObserverODERuns`` takes each run's)."""
        p = self.params
        return pickle.dumps((self.model, self.sample_time, self.Y, self.H, p.rtol, p.atol, p.min_det))

    @classmethod
    def batched(cls, instances: Sequence[ContinuousAdaptiveObserver]) -> _ContinuousBatch | None:
        """The K-run step from ``BATCH_FROM`` runs; fewer step each instance by itself (``StepEach``)."""
        return _ContinuousBatch(instances) if len(instances) >= BATCH_FROM else None


class _ContinuousBatch(DeviationBatch):
    """K observers (6)–(7) of one design, or of one ``joint_batch_key`` (each its own L and learning
    rates), each with its own x̂, Γ, step size and error scale,
    integrated together over each sample (``ObserverODERuns``, ``integrate_runs``: each run makes its
    own attempts, steps and decisions, bit for bit as alone). A run with a missing reading, which
    integrates the observer open loop, takes its instance's own ``_step``; a run whose step raises
    (an integration that cannot meet its tolerance) is out from then on, its row NaN (``failed``)."""

    def __init__(self, instances: Sequence[ContinuousAdaptiveObserver]) -> None:
        super().__init__(instances)
        self.first = instances[0]
        self.x = np.stack([e.x_hat for e in instances])
        self.gamma = np.stack([e.gamma for e in instances])
        self.h = np.array([e.h for e in instances], dtype=float)
        self.size = np.stack([e.size for e in instances])
        self.ode = ObserverODERuns([e.ode for e in instances])
        self.failed: dict[int, str] = {}

    def _step(self, dy: np.ndarray, du: np.ndarray) -> BatchEstimate:
        runs, n = len(dy), self.model.n
        x_k, gamma_k = self.x, self.gamma
        self.x, self.gamma = x_k.copy(), gamma_k.copy()
        missing = np.isnan(dy).any(axis=1)
        out = np.zeros(runs, dtype=bool)
        out[list(self.failed)] = True
        injected = np.full((runs, n), np.nan)
        live = np.flatnonzero(~missing & ~out)
        if live.size:
            with np.errstate(all="ignore"):  # NaN and inf as the one-run code's Python floats have them
                injected[live] = self._integrate(live, dy, du)
        for r in np.flatnonzero(missing & ~out).tolist():
            injected[r] = self._alone(r, dy[r], du[r])
        x, shown = x_k.copy(), gamma_k.copy()
        x[list(self.failed)] = shown[list(self.failed)] = injected[list(self.failed)] = np.nan
        diagnostics = {name: shown[:, j] for j, name in enumerate(self.first.gamma_names)}
        diagnostics |= {name: injected[:, i] for i, name in enumerate(self.first.injection_names)}
        return BatchEstimate(x, diagnostics, dict(self.failed))

    def _integrate(self, live: np.ndarray, dy: np.ndarray, du: np.ndarray) -> np.ndarray:
        """``_step`` of the runs ``live`` (every reading there): their new x̂, Γ and step in place, and
        the injected term L (Z_Γ y − H x̂) of (6), (len(live), n)."""
        first, n, params = self.first, self.model.n, self.first.params
        self.ode.raised = {}
        self.ode.hold(dy if np.isfinite(dy).all() else np.nan_to_num(dy), du)
        w = np.concatenate([self.x[live], self.gamma[live]], axis=1)
        f, J = self.ode.linearized(w, live)
        injected = f[:, :n] - mv(self.model.A, self.x[live]) - self.ode.Bu[live]
        w, h, failed = integrate_runs(
            self.ode, live, w, (f, J), first.sample_time, self.h[live], params.rtol, params.atol, self.size
        )
        self.failed |= failed
        ok = np.array([r not in failed for r in live.tolist()], dtype=bool)
        rows, w = live[ok], w[ok]
        self.x[rows], self.h[rows] = w[:, :n], h[ok]
        defined = np.abs(self.ode.weight_det(w[:, n:])) >= params.min_det  # else hold Γ, as alone
        self.gamma[rows[defined]] = w[defined, n:]
        return injected

    def _alone(self, r: int, dy: np.ndarray, du: np.ndarray) -> np.ndarray:
        """Run r's step by its own instance (a missing reading): its injected term (NaN if it raised)."""
        e = self.instances[r]
        assert isinstance(e, ContinuousAdaptiveObserver)
        e.x_hat, e.gamma, e.h, e.size = self.x[r].copy(), self.gamma[r].copy(), float(self.h[r]), self.size[r].copy()
        try:
            estimate = e._step(dy, du)
        except Exception as error:  # noqa: BLE001 (its run would end with it alone)
            self.failed[r] = f"{type(error).__name__}: {error}"
            return np.full(self.model.n, np.nan)
        self.x[r], self.gamma[r], self.h[r], self.size[r] = e.x_hat, e.gamma, e.h, e.size
        return np.array([estimate.diagnostics[name] for name in self.first.injection_names])
