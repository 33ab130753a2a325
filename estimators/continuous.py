"""The continuous-time adaptive pseudo-inverse observer of Cristofaro & Zaccarian, IEEE CDC 2016.

For ẋ = A x + B u, y = C x + φ with C = Y H, rk C = q < p:

    Z_Γ = (Yᵀ G_Γ Y)⁻¹ Yᵀ G_Γ,  G_Γ = diag(Γ)                                   (5)
    dx̂/dt = A x̂ + B u + L (Z_Γ y − H x̂)                                       (6)
    dΓ/dt = −κ_φ |det(Yᵀ G_Γ Y)| ∇_Γ|Z_Γ y − H x̂|²ᵀ + κ_Γ (1 − |Γ|²) Γ          (7)
    ∇_Γ|Z_Γ y − ẑ|²ᵀ = 2 diag(y − Y Z_Γ y) Y (Yᵀ G_Γ Y)⁻¹ (Z_Γ y − ẑ)           (8)

The estimator sees y only at the sample instants; it holds y (and u) between ticks and integrates
(6)–(7) (``ObserverODE``, with its Jacobian in closed form) by an L-stable fourth-order Rosenbrock
method under error control (``integrate``): once a fault is present the adaptation (7) is stiff
(its rate grows with κ and with the fault), which would hold an explicit method to steps far below
the sample time. The paper gives Y and H explicitly (not orthonormal); they are parameters here,
since the weights Γ it converges to depend on that choice.
"""

from __future__ import annotations

import itertools
import math
import operator
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

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


def _solve_twice(R: list[float], b: list[float], c: list[float]) -> tuple[list[float], list[float], list[float], float]:
    """z = R⁻¹ b, R⁻¹ (z − c), R⁻¹ (row by row) and det R, for the q×q matrix R given row by row; in
    closed form, in Python floats, for the usual q ≤ 2 (a LAPACK call costs more than the whole formula
    there). A singular R gives NaN, as LAPACK's inf or NaN would: the step-size control rejects the step."""
    if len(b) == 2:
        r11, r12, r21, r22 = R
        det = r11 * r22 - r12 * r21
        k = 1.0 / det if det else math.nan
        inverse = [r22 * k, -r12 * k, -r21 * k, r11 * k]
        i11, i12, i21, i22 = inverse
        z1, z2 = i11 * b[0] + i12 * b[1], i21 * b[0] + i22 * b[1]
        e1, e2 = z1 - c[0], z2 - c[1]
        return [z1, z2], [i11 * e1 + i12 * e2, i21 * e1 + i22 * e2], inverse, det
    if len(b) == 1:
        det = R[0]
        k = 1.0 / det if det else math.nan
        return [b[0] * k], [(b[0] * k - c[0]) * k], [k], det
    M = np.array(R).reshape(len(b), len(b))
    M_inv = np.linalg.inv(M)
    z = M_inv.dot(b)
    return z.tolist(), M_inv.dot(z - c).tolist(), M_inv.ravel().tolist(), float(np.linalg.det(M))


class ObserverODE:
    """dw/dt = f(w) of eq. (6)–(7) for w = [x̂; Γ], with the sample's y and u held (``hold``), and its
    Jacobian ∂f/∂w in closed form (``linearized``).

    With e = Z_Γ y − H x̂, r = y − Y Z_Γ y, s = Y R⁻¹ e, R = Yᵀ G_Γ Y, P = Y R⁻¹ Yᵀ and g = 2 r∘s the
    gradient (8): R Z_Γ y = Yᵀ G_Γ y gives ∂(Z_Γ y)/∂Γ = R⁻¹ Yᵀ diag(r), so

        ∂ẋ̂/∂x̂ = A − L H,  ∂ẋ̂/∂Γ = L R⁻¹ Yᵀ diag(r),  ∂g/∂x̂ = −2 diag(r) Y R⁻¹ H,
        ∂g/∂Γ = 2 (diag(r) Y R⁻² Yᵀ diag(r) − diag(s) P diag(r) − diag(r) P diag(s)),
        ∂|det R|/∂Γ_j = |det R| P_jj,  ∂(κ_Γ (1 − |Γ|²) Γ)/∂Γ = κ_Γ ((1 − |Γ|²) I − 2 Γ Γᵀ).

    With vectors of a few entries numpy's cost is its calls, not its arithmetic: f is two matrix
    products, and Python floats between them. R = Σ_j Γ_j Y_jᵀ Y_j (Y_j the rows of Y: R row by row
    is ``K`` Γ) and Yᵀ G_Γ y = Yᵀ diag(y) Γ are linear in w, so ``front`` w = [R row by row; Yᵀ G_Γ y;
    H x̂]. Then R Z_Γ y = Yᵀ G_Γ y and R m = e (so s = Y m) are solved in closed form, and the rest
    is linear in v = [Z_Γ y; m; 1; w; R⁻¹ row by row]: ``back`` v = [dx̂/dt; r; s; diag(r) Y;
    diag(s) Y; diag P; −2 κ_Γ Γ], the matrices row by row, y and B u entering by the column of the 1.
    """

    def __init__(
        self,
        A: np.ndarray,
        B: np.ndarray,
        H: np.ndarray,
        L: np.ndarray,
        Y: np.ndarray,
        kappa_phi: float,
        kappa_gamma: float,
    ) -> None:
        p, q = Y.shape
        n = A.shape[0]
        self.n, self.p, self.q = n, p, q
        self.B, self.H, self.L, self.Y = B, H, L, Y
        self.A_LH = A - L @ H
        self.kappa_phi, self.kappa_gamma = kappa_phi, kappa_gamma
        self.K = np.einsum("ja,jb->abj", Y, Y).reshape(q * q, p)
        self.front = np.zeros((q * q + 2 * q, n + p))  # the rows of Yᵀ diag(y) are set by ``hold``
        self.front[: q * q, n:] = self.K
        self.front[q * q + q :, :n] = H
        # back's rows (its product's parts) and columns (the parts of v)
        ends = list(itertools.accumulate((n, p, p, p * q, p * q, p, p)))
        self.dx_rows, self.r_rows, self.s_rows, self.rY_rows, self.sY_rows, self.P_rows, self.gamma_rows = (
            slice(a, b) for a, b in zip([0, *ends], ends)
        )
        z, m, self.one_column = slice(0, q), slice(q, 2 * q), 2 * q  # the column of the 1 is set by ``hold``
        x, gamma, R_inv = slice(2 * q + 1, 2 * q + 1 + n), slice(2 * q + 1 + n, 2 * q + 1 + n + p), slice(-q * q, None)
        self.back = np.zeros((ends[-1], 2 * q + 1 + n + p + q * q))
        self.back[self.dx_rows, z], self.back[self.dx_rows, x] = L, self.A_LH
        self.back[self.r_rows, z] = -Y
        self.back[self.s_rows, m] = Y
        YY = np.einsum("ia,ib->iab", Y, Y).reshape(p * q, q)
        self.back[self.rY_rows, z] = -YY  # r_i Y_ia = y_i Y_ia − Σ_b Y_ia Y_ib (Z_Γ y)_b
        self.back[self.sY_rows, m] = YY
        self.back[self.P_rows, R_inv] = self.K.T  # P_jj = Σ_ab Y_ja Y_jb (R⁻¹)_ab
        self.back[self.gamma_rows, gamma] = -2.0 * kappa_gamma * np.eye(p)
        self.identity = np.eye(n + p)
        self.identity_p = np.eye(p)

    def hold(self, y: np.ndarray, u: np.ndarray) -> None:
        """The readings and inputs held until the next sample."""
        n, q = self.n, self.q
        self.Bu = self.B.dot(u)
        self.front[q * q : q * q + q, n:] = self.Y.T * y
        one = self.back[:, self.one_column]
        one[self.dx_rows] = self.Bu
        one[self.r_rows] = y
        one[self.rY_rows] = (self.Y * y[:, None]).ravel()

    def _evaluate(
        self, w: np.ndarray
    ) -> tuple[np.ndarray, list[float], float, np.ndarray, list[float], list[float], float]:
        """f(w); and on the way R⁻¹ (row by row), det R, ``back`` v, −κ_φ |det R| g, Γ and κ_Γ (1 − |Γ|²)."""
        n, q = self.n, self.q
        front = self.front.dot(w).tolist()
        Zy, m, R_inv, det = _solve_twice(front[: q * q], front[q * q : q * q + q], front[q * q + q :])
        w_list = w.tolist()
        back = self.back.dot(np.array(Zy + m + [1.0] + w_list + R_inv))
        values = back[: self.s_rows.stop].tolist()
        gamma = w_list[n:]
        rate = -2.0 * self.kappa_phi * abs(det)
        descent = [rate * ri * si for ri, si in zip(values[self.r_rows], values[self.s_rows])]
        shrink = self.kappa_gamma * (1.0 - sum(map(operator.mul, gamma, gamma)))
        f = np.array(values[self.dx_rows] + [d + shrink * c for d, c in zip(descent, gamma)])
        return f, R_inv, det, back, descent, gamma, shrink

    def __call__(self, w: np.ndarray) -> np.ndarray:
        return self._evaluate(w)[0]

    def linearized(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """f(w) and ∂f/∂w."""
        n, p, q = self.n, self.p, self.q
        f, R_inv, det, back, descent, gamma, shrink = self._evaluate(w)
        rYR = back[self.rY_rows].reshape(p, q).dot(np.array(R_inv).reshape(q, q))  # diag(r) Y R⁻¹
        rYR_rate = rYR * (2.0 * self.kappa_phi * abs(det))
        sY = back[self.sY_rows].reshape(p, q)  # diag(s) Y
        J = np.empty((n + p, n + p))
        J[:n, :n] = self.A_LH
        J[:n, n:] = self.L.dot(rYR.T)
        J[n:, :n] = rYR_rate.dot(self.H)
        # R⁻¹ being symmetric, diag(r) Y R⁻² Yᵀ diag(r) = rYR rYRᵀ and diag(r) P diag(s) = rYR sYᵀ; and
        # −κ_φ |det R| g diag(P)ᵀ − 2 κ_Γ Γ Γᵀ is one product (the rows of diag P and −2 κ_Γ Γ are adjacent)
        rank_two = np.array([descent, gamma]).T.dot(back[self.P_rows.start : self.gamma_rows.stop].reshape(2, p))
        J[n:, n:] = rYR_rate.dot((sY - rYR).T) + sY.dot(rYR_rate.T) + rank_two + shrink * self.identity_p
        return f, J

    def weight_det(self, gamma: np.ndarray) -> float:
        """det R = det(Yᵀ G_Γ Y)."""
        R = self.K.dot(gamma)
        if self.q == 2:
            r11, r12, r21, r22 = R.tolist()
            return r11 * r22 - r12 * r21
        return float(np.linalg.det(R.reshape(self.q, self.q)))


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


# ROS4 in the transformed form of Hairer & Wanner, Solving Ordinary Differential Equations II,
# Sec. IV.7, with the L-stable parameters of its Table 7.2 (γ = 0.57282): four stages, three
# evaluations of f and one of ∂f/∂w per step, an embedded third-order solution for the error.
_GAMMA = 0.57282
_A21, _A31, _A32 = 2.0, 1.867943637803922, 0.2344449711399156
_C21, _C31, _C32 = -7.137615036412310, 2.580708087951457, 0.6515950076447975
_C41, _C42, _C43 = -2.137148994382534, -0.3214669691237626, -0.6949742501781779
_A3 = np.array([_A31, _A32])  # = a₄ⱼ
_C34 = np.array([[_C31, _C32, 0.0], [_C41, _C42, _C43]])
_SOLUTION_AND_ERROR = np.array(
    [
        [2.255570073418735, 0.2870493262186792, 0.4353179431840180, 1.093502252409163],
        [-0.2815431932141155, -0.07276199124938920, -0.1082196201495311, -1.093502252409163],
    ]
)


def _rosenbrock_step(
    ode: ObserverODE, w: np.ndarray, f: np.ndarray, J: np.ndarray, h: float, stages: np.ndarray
) -> np.ndarray:
    """One step of length h from w (f = f(w), J = ∂f/∂w there): its four stages U_i, solved into
    ``stages`` with one LU factorisation, and the rows Σ m_i U_i (the step) and Σ e_i U_i (its error)."""
    lu, pivots, _ = lapack.dgetrf(ode.identity * (1.0 / (_GAMMA * h)) - J)
    c = _C34 * (1.0 / h)
    U1 = stages[0] = lapack.dgetrs(lu, pivots, f)[0]
    stages[1] = lapack.dgetrs(lu, pivots, ode(w + _A21 * U1) + (_C21 / h) * U1)[0]
    f3 = ode(w + _A3.dot(stages[:2]))
    stages[2] = lapack.dgetrs(lu, pivots, f3 + c[0, :2].dot(stages[:2]))[0]
    stages[3] = lapack.dgetrs(lu, pivots, f3 + c[1].dot(stages[:3]))[0]
    return _SOLUTION_AND_ERROR.dot(stages)


def integrate(
    ode: ObserverODE,
    w: np.ndarray,
    linearized: tuple[np.ndarray, np.ndarray],
    span: float,
    h: float,
    rtol: float,
    atol: float,
    size: np.ndarray,
) -> tuple[np.ndarray, float]:
    """w(t + span) for the autonomous dw/dt = f(w) of ``ode``, given f(w) and ∂f/∂w (``linearized``),
    and the step to try next, from a first step h, by the Rosenbrock method above with step-size control.

    Each step solves (I/(γh) − J) U_i = f(w + Σ_{j<i} a_ij U_j) + Σ_{j<i} (c_ij/h) U_j, i = 1 … 4, with
    J = ∂f/∂w at w (a₄ⱼ = a₃ⱼ), and takes w + Σ m_i U_i; Σ e_i U_i, its difference from the embedded
    third-order solution, estimates its error. A step is kept when every |error_i| ≤ atol + rtol s_i,
    s_i the largest |w_i| so far (``size``, updated in place): relative to the size each component has
    had, not to its current value, which crosses zero. With ρ = max_i |error_i| / (atol + rtol s_i),
    the step proposed next is 0.9 ρ^(−1/4) h, within h/5 … 5 h.

    The steps left in the span are of equal length, as many as the proposed step needs, rather than
    proposed steps and a short last one: the short step's small error proposes a first step for the
    next sample that is often too long and rejected, while equal steps, each somewhat shorter than
    proposed, seldom are (in ``bench/estimator_step.py``: 2.45 attempts for 2.0 kept steps per sample
    with a short last step, 2.08 for 1.95 with equal steps).

    I/(γh) − J is factorised once per step (LAPACK's LU) and each stage solved with its factors: at
    this size numpy's inv and solve cost several times more, in their checks, than the arithmetic.
    A singular matrix gives inf or NaN stages, which the error test rejects.
    """
    t = 0.0
    f, J = linearized
    stages = np.empty((4, w.size))
    while True:
        remaining = span - t
        h = remaining / max(1, math.ceil(remaining / h - 1e-9))  # (− 1e-9: no extra step for a rounding error)
        step_and_error = _rosenbrock_step(ode, w, f, J, h, stages)
        w_new = w + step_and_error[0]
        ratios = [
            abs(e) / (atol + rtol * max(s, abs(v)))
            for e, s, v in zip(step_and_error[1].tolist(), size.tolist(), w_new.tolist())
        ]
        ratio = math.nan if math.isnan(sum(ratios)) else max(ratios)  # max() would pass over a NaN
        # the next step: at most 5 times longer; a fifth as long if the error is not finite (NaN included)
        factor = 5.0 if ratio == 0 else min(5.0, max(0.2, 0.9 * ratio**-0.25))
        if ratio <= 1.0:
            t, w = t + h, w_new
            np.maximum(size, np.abs(w), out=size)
            if t >= span * (1 - 1e-12):
                return w, h * factor
            f, J = ode.linearized(w)
        h *= factor
        if h < 1e-12 * span:
            raise FloatingPointError("the observer's ODE cannot be integrated to the requested tolerance")
