"""Adaptive pseudoinverse observers for output-redundant discrete-time plants, and their baselines.

Cristofaro & Zaccarian, "Adaptive Pseudoinverse Observers for Output Redundant Discrete-Time
Linear Systems", IEEE TAC 2024. The plant is x⁺ = A x + B u, y = C x + φ with a redundant output
(rk C = q < p) and an unknown bias φ. The scheme (Fig. 1) is a cascade:

1. the asymptotic bias estimator (7a)–(7c), ``BiasEstimator``, whose φ̂ → φ exponentially
   (Proposition 1);
2. the optimizer z⁺ ∈ G_z(z, φ̂), a line search over the coordinate directions that decreases
   |Γ(φ̂) z| (36)–(37e), ``estimators.adaptive_law.optimizer_step``;
3. the selector (17), or its logic-enhanced form (52), ``adaptive_law.select``: s takes z unless R(z) is
   too close to singular (|det R(z)| ≤ ε), in which case s is held and h = 1;
4. the observer (13) with the weighted pseudoinverse Π(s) = R(s)⁻¹ Γ(s) (14), or with residual
   injection (53): x̂⁺ = A x̂ + B u + L Π(s)(y − C x̂ − h φ̂).

Algorithm 1 (scaling and low-pass filtering of φ̂ before the optimizer) handles a bias of
constant direction and varying magnitude, φ_k = g_k φ̄ (35). The baseline (56) injects φ̂ instead:
x̂⁺ = A x̂ + B u + L (Y†(y − φ̂) − H x̂), optionally with φ̂ low-pass filtered.

Beyond the paper, off by default: a dead zone on the adaptation (``dead_zone`` δ > 0), the optimizer
held while |φ̂_k| < δ, a standard robust modification of adaptive laws (Ioannou & Sun, *Robust
Adaptive Control*, 1996, Ch. 8, "Dead zone"): without a bias to identify, φ̂ is noise and z
would wander over 𝒮_ε (docs/tac2024.md, "Under measurement noise").

All estimators here work on the outputs recombined by the orthogonal Σ of the construction
after Assumption 2 (Σ = I when the plant's (Y, H) already satisfy it, as in the paper's case study).
Ticks with a missing reading are open-loop predictions: no correction, optimizer and selector held.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from estimators.adaptive_law import (
    optimizer_step,
    optimizer_steps,
    scale_and_filter,
    scale_and_filter_runs,
    select,
    select_runs,
)
from estimators.base import Estimate, Estimator, ParameterError, initial_state
from estimators.batched import BatchEstimate, DeviationBatch, mv, norms
from estimators.design import (
    AssumptionError,
    assumption2_factorization,
    check_assumption1,
    observer_gain,
    output_factorization,
    weighted_pseudoinverse,
)
from estimators.diagnostics import Diagnostic, DiagnosticKind
from estimators.model import LinearModel

# -- the bias estimator (Section III) ----------------------------------------------------------


class BiasEstimator:
    """The asymptotic bias estimator of eq. (7a)–(7c), for y = Y H x + φ.

        ξ⁺ = A ξ + B u + M ℙ_Y (y − C ξ)                              (7a)
        η  = ℙ_Y y − H ξ                                              (7b)
        φ̂  = Y (I + H (I − A)⁻¹ M) η + (I − Y ℙ_Y) y,  ℙ_Y = (YᵀY)⁻¹Yᵀ   (7c)

    With A − M H Schur and A − I nonsingular, φ̂ − φ → 0 exponentially (Proposition 1).
    """

    def __init__(
        self, A: np.ndarray, B: np.ndarray, Y: np.ndarray, H: np.ndarray, M: np.ndarray, xi0: np.ndarray | None = None
    ) -> None:
        n, p = A.shape[0], Y.shape[0]
        self.A, self.B, self.H, self.M = A, B, H, M
        self.C = Y @ H
        self.P_Y = np.linalg.solve(Y.T @ Y, Y.T)
        self.output_gain = Y @ (np.eye(H.shape[0]) + H @ np.linalg.solve(np.eye(n) - A, M))  # (7c)
        self.complement = np.eye(p) - Y @ self.P_Y
        self.xi = np.zeros(n) if xi0 is None else np.array(xi0, dtype=float)

    def estimate(self, y: np.ndarray) -> np.ndarray:
        """φ̂_k from y_k and the current ξ_k, eq. (7b)–(7c)."""
        eta = self.P_Y @ y - self.H @ self.xi
        return self.output_gain @ eta + self.complement @ y

    def update(self, y: np.ndarray, u: np.ndarray) -> None:
        """ξ_{k+1}, eq. (7a)."""
        self.xi = self.A @ self.xi + self.B @ u + self.M @ (self.P_Y @ (y - self.C @ self.xi))

    def predict(self, u: np.ndarray) -> None:
        """ξ_{k+1} without a measurement (a tick with a missing reading)."""
        self.xi = self.A @ self.xi + self.B @ u


# -- estimators ---------------------------------------------------------------------------------


PHI_HAT = Diagnostic("phihat_{}", "", "estimated bias φ̂, eq. (7c) ({})", 1e6, 1e-6, DiagnosticKind.BIAS_ESTIMATE)
OPTIMIZER = Diagnostic("z_{}", "", "optimizer state z, eq. (16) ({})", 1.0, 1e-6, DiagnosticKind.OPTIMIZER)
SELECTOR = Diagnostic("s_{}", "", "selector state s, eq. (17) ({})", 1.0, 1e-6, DiagnosticKind.SELECTOR)
LOGIC = Diagnostic("h", "", "selector logic h: 1 while z is refused, eq. (52)", 1.0, 1.0, DiagnosticKind.LOGIC)
INJECTION = Diagnostic("inj_{}", "", "output injection added to x̂⁺ ({})", 1e6, 1e-6, DiagnosticKind.INJECTION)
"""The diagnostics of the observers here: φ̂, z and s per output, h, the injection per state."""


def _gain(model: LinearModel, H: np.ndarray, poles: tuple[float, ...], name: str) -> np.ndarray:
    if np.any(np.abs(np.asarray(poles)) >= 1.0):
        raise ParameterError(name, f"{list(poles)}: every pole must lie inside the unit circle (A − L H Schur)")
    try:
        return observer_gain(model.A, H, poles)
    except ValueError as error:
        raise ParameterError(name, str(error)) from None


def _check_model(model: LinearModel) -> None:
    try:
        check_assumption1(model.A, model.C, discrete=True)
    except AssumptionError as error:
        raise ParameterError("model", f"{error} (TAC 2024)") from None


def _unit(values: tuple[float, ...] | None, p: int, name: str) -> np.ndarray:
    if values is None:
        return np.full(p, 1.0 / np.sqrt(p))
    v = np.asarray(values, dtype=float)
    if v.shape != (p,) or not np.linalg.norm(v) > 0:
        raise ParameterError(name, f"expected {p} weights, not all zero")
    return v / np.linalg.norm(v)


@dataclass(frozen=True)
class AdaptiveParams:
    poles: tuple[float, ...] = (0.75, 0.8, 0.85, 0.9)
    """Spectrum of A − L H, the observer (13) (Sec. VII: {0.75, 0.8, 0.85, 0.9})."""
    bias_poles: tuple[float, ...] = (0.0, 0.0, 0.01, 0.01)
    """Spectrum of A − M H, the bias estimator (7) (Sec. VII: {0, 0, 0.01, 0.01}); repeated poles allowed."""
    epsilon: float = 0.01
    """Selector threshold ε of 𝒮_ε (15): z is taken only where |det R(z)| > ε."""
    injection: bool = False
    """Residual injection (52)–(53): inject h φ̂ while the selector refuses z."""
    filter: float | None = None
    """τ of Algorithm 1 (scaling and low-pass filtering of φ̂ before the optimizer); None: off."""
    eps_phi: float = 1e-3
    """Regularization ε_φ of Algorithm 1 (i), in output units."""
    dead_zone: float = 0.0
    """δ of a dead zone, beyond the paper: the optimizer holds z while |φ̂_k| < δ (output units), so that
    measurement noise alone does not move it; 0: off, the paper's law. Set it above φ̂'s noise."""
    z0: tuple[float, ...] | None = None
    """Initial optimizer and selector states z₀ = s₀; None: the uniform weights 𝟙/√p."""
    x0: tuple[float, ...] | None = None
    """Initial estimate x̂₀ (absolute), also ξ₀; None: the operating point."""


class AdaptivePseudoinverseObserver(Estimator):
    """The adaptive pseudoinverse observer (7), (13), (16), (17), (37) of TAC 2024, optionally with
    residual injection (52)–(53) and Algorithm 1.

    Diagnostics each tick k: φ̂_k (in the sensors' coordinates), z_k, s_k, h_k and the injected
    term L Π(s_k)(y_k − C x̂_k − h_k φ̂_k).
    """

    kind = "adaptive"
    Params = AdaptiveParams

    def __init__(self, model: LinearModel, params: AdaptiveParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        _check_model(model)
        try:
            self.Y, self.H, self.Sigma = assumption2_factorization(model.C)
        except AssumptionError as error:
            raise ParameterError("model", str(error)) from None
        p = model.p
        if not 0 < params.epsilon:
            raise ParameterError("epsilon", f"{params.epsilon}: the selector threshold must be positive")
        if params.filter is not None and not 0 < params.filter < 1:
            raise ParameterError("filter", f"{params.filter}: Algorithm 1 needs τ in (0, 1)")
        if not params.eps_phi > 0:
            raise ParameterError("eps_phi", "must be positive")
        if not params.dead_zone >= 0:
            raise ParameterError("dead_zone", f"{params.dead_zone}: the dead zone must be 0 (off) or positive")
        self.C = self.Sigma @ model.C
        self.L = _gain(model, self.H, params.poles, "poles")
        self.M = _gain(model, self.H, params.bias_poles, "bias_poles")
        self.x_hat = initial_state(model, params.x0)
        self.bias = BiasEstimator(model.A, model.B, self.Y, self.H, self.M, self.x_hat)
        self.z = _unit(params.z0, p, "z0")
        if abs(np.linalg.det((self.Y.T * self.z) @ self.Y)) <= params.epsilon:
            raise ParameterError(
                "z0", f"|det R(z0)| is not above epsilon = {params.epsilon}: the selector would never start"
            )
        self.s = self.z.copy()
        self.h = 0
        self.phi_filtered = np.zeros(p)
        self.phi_hat = np.zeros(p)

    @classmethod
    def diagnostic_channels(cls, states: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        return [
            *PHI_HAT.over(outputs),
            *OPTIMIZER.over(outputs),
            *SELECTOR.over(outputs),
            LOGIC,
            *INJECTION.over(states),
        ]

    def _step(self, dy: np.ndarray, du: np.ndarray) -> Estimate:
        A, B = self.model.A, self.model.B
        x_k = self.x_hat
        injected = np.zeros(self.model.n)
        z, s, h = self.z, self.s, self.h
        if np.isnan(dy).any():
            self.x_hat = A @ x_k + B @ du
            self.bias.predict(du)
        else:
            y = self.Sigma @ dy
            phi_hat = self.bias.estimate(y)
            self.phi_hat = phi_hat
            innovation = y - self.C @ x_k - (h * phi_hat if self.params.injection else 0.0)
            injected = self.L @ (weighted_pseudoinverse(self.Y, s) @ innovation)
            self.x_hat = A @ x_k + B @ du + injected  # (13) / (53)
            if self.params.filter is not None:  # Algorithm 1
                self.phi_filtered = scale_and_filter(
                    phi_hat, self.phi_filtered, self.params.filter, self.params.eps_phi
                )
            driving = phi_hat if self.params.filter is None else self.phi_filtered
            if np.linalg.norm(phi_hat) >= self.params.dead_zone:  # always with δ = 0, the paper's law
                self.z = optimizer_step(z, driving, self.Y)  # (16), (37e)
            self.s, self.h = select(s, z, self.Y, self.params.epsilon)  # (17) / (52)
            self.bias.update(y, du)  # (7a)
        outputs = self.model.outputs
        diagnostics = PHI_HAT.values(outputs, self.Sigma.T @ self.phi_hat)
        diagnostics |= OPTIMIZER.values(outputs, z) | SELECTOR.values(outputs, s) | {LOGIC.name: float(h)}
        diagnostics |= INJECTION.values(self.model.states, injected)
        return Estimate(x_k.copy(), diagnostics)

    @classmethod
    def batched(cls, instances: Sequence[AdaptivePseudoinverseObserver]) -> _AdaptiveBatch:
        return _AdaptiveBatch(instances)

    def bias_effect(self, diagnostics: dict[str, float], phi: np.ndarray) -> np.ndarray:
        """The bias's effect on the injection, Π(s)(Σφ − h Σφ̂) (R(s)⁻¹Γ(φ)s of eq. (19)–(20), (54))."""
        s = SELECTOR.read(diagnostics, self.model.outputs)
        residual = self.Sigma @ phi
        if self.params.injection and diagnostics.get(LOGIC.name):
            residual = residual - self.Sigma @ PHI_HAT.read(diagnostics, self.model.outputs)
        return weighted_pseudoinverse(self.Y, s) @ residual


class _AdaptiveBatch(DeviationBatch):
    """K adaptive observers of one design: the observer (13), the bias estimator (7), Π(s) of each
    run's own selector (14) and the adaptation (Algorithm 1, the dead zone, the optimizer (37e), the
    selector (17)/(52): ``estimators.adaptive_law``'s K-run forms) on arrays with a leading run axis;
    a run with a missing reading predicts and holds its adaptation, as its step does."""

    def __init__(self, instances: Sequence[AdaptivePseudoinverseObserver]) -> None:
        super().__init__(instances)
        self.first = instances[0]
        self.x = np.stack([e.x_hat for e in instances])
        self.xi = np.stack([e.bias.xi for e in instances])
        self.z = np.stack([e.z for e in instances])
        self.s = np.stack([e.s for e in instances])
        self.h = np.array([e.h for e in instances])
        self.phi_hat = np.stack([e.phi_hat for e in instances])
        self.phi_filtered = np.stack([e.phi_filtered for e in instances])

    def _step(self, dy: np.ndarray, du: np.ndarray) -> BatchEstimate:
        A, B = self.model.A, self.model.B
        first, bias = self.first, self.first.bias
        x_k, xi, z, s, h = self.x, self.xi, self.z, self.s, self.h
        missing = np.isnan(dy).any(axis=1)
        rows = np.flatnonzero(~missing) if missing.any() else slice(None)  # the runs with every reading
        x_next = mv(A, x_k) + mv(B, du)
        xi_next = mv(bias.A, xi) + mv(bias.B, du)  # (7a) without a measurement: a run with a missing reading
        injected = np.zeros_like(x_k)
        if not missing.all():
            y = mv(first.Sigma, dy[rows])
            phi_hat = mv(bias.output_gain, mv(bias.P_Y, y) - mv(bias.H, xi[rows])) + mv(bias.complement, y)  # (7c)
            self.phi_hat[rows] = phi_hat
            innovation = y - mv(first.C, x_k[rows]) - (h[rows][:, None] * phi_hat if first.params.injection else 0.0)
            gamma = first.Y.T * s[rows][:, None, :]  # Π(s) = (Γ(s) Y)⁻¹ Γ(s), each run's s (14)
            allocation = np.linalg.solve(gamma @ first.Y, gamma)
            injected[rows] = mv(first.L, np.matmul(allocation, innovation[..., None])[..., 0])
            x_next[rows] = x_next[rows] + injected[rows]  # (13) / (53)
            xi_next[rows] = xi_next[rows] + mv(bias.M, mv(bias.P_Y, y - mv(bias.C, xi[rows])))  # (7a)
            self.z, self.s, self.h = z.copy(), s.copy(), h.copy()
            self.z[rows], self.s[rows], self.h[rows] = self._adapt(rows, phi_hat)
        outputs, states = self.model.outputs, self.model.states
        phi_shown = mv(first.Sigma.T, self.phi_hat)
        diagnostics = {PHI_HAT.named(o): phi_shown[:, i] for i, o in enumerate(outputs)}
        diagnostics |= {OPTIMIZER.named(o): z[:, i] for i, o in enumerate(outputs)}
        diagnostics |= {SELECTOR.named(o): s[:, i] for i, o in enumerate(outputs)}
        diagnostics[LOGIC.name] = h.astype(float)
        diagnostics |= {INJECTION.named(x): injected[:, i] for i, x in enumerate(states)}
        self.x, self.xi = x_next, xi_next
        return BatchEstimate(x_k.copy(), diagnostics)

    def _adapt(self, rows: np.ndarray | slice, phi_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """z⁺, s⁺ and h⁺ of the given runs from their φ̂: Algorithm 1, the dead zone, the optimizer
        (16), (37e) and the selector (17) / (52) on z_k, as the single step has them."""
        Y, params = self.first.Y, self.first.params
        z, s = self.z[rows], self.s[rows]
        driving = phi_hat
        if params.filter is not None:  # Algorithm 1
            driving = scale_and_filter_runs(phi_hat, self.phi_filtered[rows], params.filter, params.eps_phi)
            self.phi_filtered[rows] = driving
        moving = norms(phi_hat) >= params.dead_zone  # with δ = 0 always (a finite φ̂), the paper's law
        z_next = np.where(moving[:, None], optimizer_steps(z, driving, Y), z)
        return (z_next, *select_runs(s, z, Y, params.epsilon))


@dataclass(frozen=True)
class InjectionParams:
    poles: tuple[float, ...] = (0.75, 0.8, 0.85, 0.9)
    """Spectrum of A − L H."""
    bias_poles: tuple[float, ...] = (0.0, 0.0, 0.01, 0.01)
    """Spectrum of A − M H of the bias estimator (7)."""
    filter: float | None = None
    """τ of a first-order low-pass φ̂_f ← (1 − τ) φ̂_f + τ φ̂ on the injected estimate; None: unfiltered."""
    x0: tuple[float, ...] | None = None
    """Initial estimate x̂₀ (absolute), also ξ₀; None: the operating point."""


class InjectionObserver(Estimator):
    """The baseline observer (56) of TAC 2024 Sec. VII-A: x̂⁺ = A x̂ + B u + L (Y†(y − φ̂) − H x̂), with
    φ̂ from the bias estimator (7), optionally low-pass filtered ("injection of the filtered estimation").

    Diagnostics: the injected φ̂ and the injected term.
    """

    kind = "injection"
    Params = InjectionParams

    def __init__(self, model: LinearModel, params: InjectionParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        _check_model(model)
        if params.filter is not None and not 0 < params.filter <= 1:
            raise ParameterError("filter", f"{params.filter}: the low-pass needs τ in (0, 1]")
        self.Y, self.H = output_factorization(model.C)
        self.L = _gain(model, self.H, params.poles, "poles")
        M = _gain(model, self.H, params.bias_poles, "bias_poles")
        self.x_hat = initial_state(model, params.x0)
        self.bias = BiasEstimator(model.A, model.B, self.Y, self.H, M, self.x_hat)
        self.phi_used = np.zeros(model.p)

    @classmethod
    def diagnostic_channels(cls, states: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        return [*PHI_HAT.over(outputs), *INJECTION.over(states)]

    def _step(self, dy: np.ndarray, du: np.ndarray) -> Estimate:
        A, B = self.model.A, self.model.B
        x_k = self.x_hat
        injected = np.zeros(self.model.n)
        if np.isnan(dy).any():
            self.x_hat = A @ x_k + B @ du
            self.bias.predict(du)
        else:
            phi_hat = self.bias.estimate(dy)
            tau = self.params.filter
            self.phi_used = phi_hat if tau is None else (1.0 - tau) * self.phi_used + tau * phi_hat
            injected = self.L @ (self.bias.P_Y @ (dy - self.phi_used) - self.H @ x_k)
            self.x_hat = A @ x_k + B @ du + injected  # (56)
            self.bias.update(dy, du)
        diagnostics = PHI_HAT.values(self.model.outputs, self.phi_used) | INJECTION.values(self.model.states, injected)
        return Estimate(x_k.copy(), diagnostics)

    def bias_effect(self, diagnostics: dict[str, float], phi: np.ndarray) -> np.ndarray:
        """Y†(φ − φ̂): what the bias leaves in the injection of (56)."""
        phi_hat = PHI_HAT.read(diagnostics, self.model.outputs)
        return self.bias.P_Y @ (phi - phi_hat)

    @classmethod
    def batched(cls, instances: Sequence[InjectionObserver]) -> _InjectionBatch:
        return _InjectionBatch(instances)


class _InjectionBatch(DeviationBatch):
    """K observers (56) with their bias estimators (7) of one design: x̂, ξ and the injected φ̂ of
    shape (K, ·) in the stacked kernels; a run with a missing reading predicts, as its step does."""

    def __init__(self, instances: Sequence[InjectionObserver]) -> None:
        super().__init__(instances)
        self.first = instances[0]
        self.x = np.stack([e.x_hat for e in instances])
        self.xi = np.stack([e.bias.xi for e in instances])
        self.phi_used = np.stack([e.phi_used for e in instances])

    def _step(self, dy: np.ndarray, du: np.ndarray) -> BatchEstimate:
        A, B = self.model.A, self.model.B
        first, bias, tau = self.first, self.first.bias, self.first.params.filter
        x_k, xi = self.x, self.xi
        whole = ~np.isnan(dy).any(axis=1)
        phi_hat = mv(bias.output_gain, mv(bias.P_Y, dy) - mv(bias.H, xi)) + mv(bias.complement, dy)  # (7b)-(7c)
        phi_used = phi_hat if tau is None else (1.0 - tau) * self.phi_used + tau * phi_hat
        injected = mv(first.L, mv(bias.P_Y, dy - phi_used) - mv(first.H, x_k))
        x_next = mv(A, x_k) + mv(B, du) + injected  # (56)
        xi_next = mv(bias.A, xi) + mv(bias.B, du) + mv(bias.M, mv(bias.P_Y, dy - mv(bias.C, xi)))  # (7a)
        if not whole.all():  # a missing reading: predict x̂ and ξ, keep φ̂, inject nothing
            rows = ~whole
            x_next[rows] = mv(A, x_k[rows]) + mv(B, du[rows])
            xi_next[rows] = mv(bias.A, xi[rows]) + mv(bias.B, du[rows])
            phi_used = np.where(rows[:, None], self.phi_used, phi_used)
            injected[rows] = 0.0
        self.x, self.xi, self.phi_used = x_next, xi_next, phi_used
        diagnostics = {PHI_HAT.named(o): phi_used[:, i] for i, o in enumerate(self.model.outputs)}
        diagnostics |= {INJECTION.named(x): injected[:, i] for i, x in enumerate(self.model.states)}
        return BatchEstimate(x_k.copy(), diagnostics)
