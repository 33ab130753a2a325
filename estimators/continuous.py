"""The continuous-time adaptive pseudo-inverse observer of Cristofaro & Zaccarian, IEEE CDC 2016.

For ẋ = A x + B u, y = C x + φ with C = Y H, rk C = q < p:

    Z_Γ = (Yᵀ G_Γ Y)⁻¹ Yᵀ G_Γ,  G_Γ = diag(Γ)                                   (5)
    dx̂/dt = A x̂ + B u + L (Z_Γ y − H x̂)                                       (6)
    dΓ/dt = −κ_φ |det(Yᵀ G_Γ Y)| ∇_Γ|Z_Γ y − H x̂|²ᵀ + κ_Γ (1 − |Γ|²) Γ          (7)
    ∇_Γ|Z_Γ y − ẑ|²ᵀ = 2 diag(y − Y Z_Γ y) Y (Yᵀ G_Γ Y)⁻¹ (Z_Γ y − ẑ)           (8)

The estimator sees y only at the sample instants; it holds y (and u) between ticks and integrates
(6)–(7) with an L-stable Rosenbrock 2(3) pair under error control (``rtol``, ``atol``): once a
fault is present the adaptation (7) is stiff (its rate grows with κ and with the fault), which
would hold an explicit method to steps far below the sample time. The paper gives Y and H
explicitly (not orthonormal); they are parameters here, since the weights Γ it converges to depend
on that choice.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.base import Diagnostic, DiagnosticKind, Estimate, Estimator, ParameterError, initial_state
from estimators.design import AssumptionError, check_assumption1, output_factorization
from estimators.model import LinearModel


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
        self.h = self.sample_time  # the step size carries over from sample to sample

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
        x_k, gamma_k = self.x_hat.copy(), self.gamma.copy()
        if np.isnan(dy).any():
            # a missing reading: integrate the observer open loop, weights frozen
            injected = np.zeros(self.model.n)
            self._integrate(np.nan_to_num(dy), du, adapt=False)
        else:
            injected = self.L @ (pseudoinverse(self.Y, gamma_k) @ dy - self.H @ x_k)
            self._integrate(dy, du, adapt=True)
        diagnostics = {f"gamma_{o}": float(g) for o, g in zip(self.model.outputs, gamma_k)}
        diagnostics |= {f"inj_{s}": float(v) for s, v in zip(self.model.states, injected)}
        return Estimate(x_k, diagnostics)

    def _integrate(self, y: np.ndarray, u: np.ndarray, adapt: bool) -> None:
        A, H, Y, n = self.model.A, self.H, self.Y, self.model.n
        L = self.L if adapt else np.zeros_like(self.L)
        kp, kg = (self.kappa_phi, self.kappa_gamma) if adapt else (0.0, 0.0)
        Bu = self.model.B @ u

        def f(w: np.ndarray) -> np.ndarray:
            return np.concatenate(vector_field(w[:n], w[n:], y, Bu, A, H, L, Y, kp, kg))

        w = integrate(
            f, np.concatenate([self.x_hat, self.gamma]), self.sample_time, self, self.params.rtol, self.params.atol
        )
        self.x_hat = w[:n]
        if abs(np.linalg.det((Y.T * w[n:]) @ Y)) >= self.params.min_det:
            self.gamma = w[n:]  # else hold Γ: Z_Γ would be undefined (the reset of Remark 1 is not attempted)

    def bias_effect(self, diagnostics: dict[str, float], phi: np.ndarray) -> np.ndarray:
        """h_Γ = Z_Γ φ (Sec. IV), the part of the injection due to the fault."""
        gamma = np.array([diagnostics[f"gamma_{o}"] for o in self.model.outputs])
        return pseudoinverse(self.Y, gamma) @ phi


_D = 1.0 / (2.0 + np.sqrt(2.0))
_E32 = 6.0 + np.sqrt(2.0)


def integrate(f, w: np.ndarray, span: float, stepper, rtol: float, atol: float) -> np.ndarray:
    """w(t + span) for the autonomous dw/dt = f(w) by the L-stable Rosenbrock 2(3) pair of
    Shampine & Reichelt (MATLAB's ode23s), with step-size control.

    W = I − h d J with d = 1/(2 + √2) and J = ∂f/∂w (forward differences, once per call);
    k₁ = W⁻¹ f(w), k₂ = W⁻¹(f(w + h k₁/2) − k₁) + k₁, w⁺ = w + h k₂,
    k₃ = W⁻¹(f(w⁺) − e₃₂(k₂ − f(w + h k₁/2)) − 2(k₁ − f(w))), error h (k₁ − 2k₂ + k₃)/6.
    A step is kept when max |error_i| / (atol + rtol max(|w_i|, |w⁺_i|)) ≤ 1. ``stepper.h`` is the
    first step tried and keeps the last good one, so a smooth stretch costs one step per sample.
    """
    n = w.size
    f0 = f(w)
    J = np.empty((n, n))
    for j in range(n):
        delta = 1.5e-8 * max(1.0, abs(w[j]))
        shifted = w.copy()
        shifted[j] += delta
        J[:, j] = (f(shifted) - f0) / delta
    t, h = 0.0, min(stepper.h, span)
    identity = np.eye(n)
    while True:
        h = min(h, span - t)
        W_inv = np.linalg.inv(identity - h * _D * J)
        k1 = W_inv @ f0
        f1 = f(w + 0.5 * h * k1)
        k2 = W_inv @ (f1 - k1) + k1
        w_new = w + h * k2
        f2 = f(w_new)
        k3 = W_inv @ (f2 - _E32 * (k2 - f1) - 2.0 * (k1 - f0))
        error = h / 6.0 * (k1 - 2.0 * k2 + k3)
        ratio = np.max(np.abs(error) / (atol + rtol * np.maximum(np.abs(w), np.abs(w_new))))
        if ratio <= 1.0:
            t, w, f0 = t + h, w_new, f2
            if t >= span * (1 - 1e-12):
                stepper.h = max(h, stepper.h if h >= span - t + h - 1e-15 else h)
                return w
            stepper.h = h
        h *= min(5.0, max(0.2, 0.8 * ratio ** (-1.0 / 3.0))) if ratio > 0 else 5.0
        if h < 1e-12 * span:
            raise FloatingPointError("the observer's ODE cannot be integrated to the requested tolerance")
