"""Thresholds of the COFD residuals from a declared environment: a constant current the observers
learn, band-limited waves whose filtered amplitude is computed, and the design model's error.

Cristofaro & Johansen (shared/papers/003), Sec. 3–4, with b(t) of the vessel's environment model
(mjcf/vessel.py, ``EnvironmentDisturbance``). Without faults, residual component i of observer
O_h is the filtered disturbance r_i(t) = ∫₀^t h_i(s) b(t − s) ds with h_i(s) = c_iᵀ e^{F s} R E
(docs/vessel-fdi.md). The paper's class |b(t)|₂ ≤ ε gives the flat bound ε ∫₀^∞ |h_i| ds
(``estimators.cofd.residual_bounds``). The declared environment is a smaller class,

    b(t) = b_c + Σ_k a_k sin(ω_k t + φ_k) [cos β_k(t), sin β_k(t), 0] + Σ_k n_k sin(ω_k t + θ_k) e_3 + d(t),

|b_c| ≤ ``current`` (constant, direction unknown), Σ a_k ≤ ``wave_force``, Σ n_k ≤ ``wave_moment``,
ω_k in the band of ``wave_periods``, |β̇_k| ≤ κ = ``swing`` · 2π/``swing_period``, and the design
model's error d(t), |d(t)|₂ ≤ ``model_error`` + ``model_error_ratio`` · |E⁺ẏ(t)|, entering like b.
The current's effect g_i b_c is a constant the node learns as the mean m̂_i of r_i over a
fault-free window [t₁, t₂); the waves' effect is bounded by the band's gain |H_i(jω)|,
H_i(jω) = c_iᵀ(jωI − F)⁻¹ R E, below ∫|h_i| by as much as F filters the band; ``centred_bounds``
bounds |r_i(t) − m̂_i| for t ≥ t₂ over the whole class, ``InertialAllowance`` the model error's
part that grows with the accelerations, and ``ResidualTest`` applies them tick by tick.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.integrate
import scipy.linalg

from estimators.base import ParameterError

if TYPE_CHECKING:
    from estimators.cofd_design import COFDObserver

FORCE, MOMENT = (0, 1), (2,)
"""The environment's inputs among E's columns: the horizontal force (b_x, b_y), the yaw moment b_n."""


@dataclass(frozen=True)
class DeclaredEnvironment:
    """The declared class of the vessel's environment disturbance (the keywords of mjcf/vessel.py's
    ``EnvironmentDisturbance.random``), the design model's error, and the window in which the
    node learns the residuals' means: parameters of kind ``cofd`` (``COFDParams`` extends it)."""

    current: float | None = None
    """Bound on the constant current force |b_c| (N). Declaring it (0 for none) switches to the
    environment's thresholds after the learning window; None: the flat thresholds of |b| ≤ ε only."""
    wave_force: float = 0.0
    """Sum of the wave force amplitudes (N)."""
    wave_moment: float = 0.0
    """Sum of the wave yaw moment amplitudes (N m)."""
    wave_periods: tuple[float, ...] = (6.0, 10.0)
    """The range of the waves' periods (s)."""
    swing: float = np.pi / 6
    """The wave direction swings by at most this much (rad) about its mean ..."""
    swing_period: float = 200.0
    """... with this period (s): |β̇| ≤ κ = swing · 2π / swing_period."""
    model_error: float = 0.0
    """Bound on the force the design model misses at rest (N), entering like b (flat, not learned)."""
    model_error_ratio: float = 0.0
    """... plus this share of the inertial force |E⁺ ẏ| (``InertialAllowance``): |d(t)|₂ ≤
    model_error + model_error_ratio · |E⁺ ẏ(t)|."""
    learning: tuple[float, ...] = (5.0, 15.0)
    """The fault-free window [t₁, t₂) (s from the node's first sample) whose samples give m̂."""

    @property
    def declared(self) -> bool:
        return self.current is not None

    @property
    def bound(self) -> float:
        """|b(t)|₂ + |d(t)|₂ ≤ current + hypot(wave_force, wave_moment) + model_error at rest (the
        environment model splits both sums equally among its components, so Σ_k hypot(a_k, n_k) =
        hypot(wave_force, wave_moment))."""
        return (self.current or 0.0) + float(np.hypot(self.wave_force, self.wave_moment)) + self.model_error

    @property
    def band(self) -> tuple[float, float]:
        """The waves' angular frequencies (rad/s), lowest first."""
        return 2.0 * np.pi / self.wave_periods[1], 2.0 * np.pi / self.wave_periods[0]

    @property
    def turn_rate(self) -> float:
        """κ, the largest rate of the wave direction (rad/s)."""
        return self.swing * 2.0 * np.pi / self.swing_period

    def check(self, sample_time: float) -> None:
        """ParameterError naming the first declared value that makes no class."""
        for name in ("current", "wave_force", "wave_moment", "swing", "model_error", "model_error_ratio"):
            value = getattr(self, name)
            if value is not None and not value >= 0:
                raise ParameterError(name, f"must be at least 0, got {value}")
        if len(self.wave_periods) != 2 or not 2 * sample_time < self.wave_periods[0] <= self.wave_periods[1]:
            raise ParameterError(
                "wave_periods",
                f"give [shortest, longest] (s), longer than two samples ({2 * sample_time:g} s), got "
                f"{list(self.wave_periods)}",
            )
        if not self.swing_period > 0:
            raise ParameterError("swing_period", f"must be positive, got {self.swing_period}")
        if len(self.learning) != 2 or not 0 <= self.learning[0] <= self.learning[1] - sample_time:
            raise ParameterError(
                "learning", f"give [start, end] (s), 0 ≤ start, at least one sample long, got {list(self.learning)}"
            )


def _integral(
    F: np.ndarray,
    left: np.ndarray,
    right: np.ndarray,
    weight: Callable[[float], float] | None = None,
    start: float = 0.0,
) -> np.ndarray:
    """∫_start^∞ w(s) |(left e^{F s} right)_i|₂ ds per row i (w = 1 by default), integrated until
    e^{F s} has decayed by e^(−40)."""
    horizon = start + 40.0 / -np.max(np.linalg.eigvals(F).real)

    def integrand(s: float) -> np.ndarray:
        gain = np.linalg.norm(left @ scipy.linalg.expm(F * s) @ right, axis=1)
        return gain if weight is None else weight(s) * gain

    value, _ = scipy.integrate.quad_vec(integrand, start, horizon, epsrel=1e-10, epsabs=0.0)
    return value


def band_gains(
    F: np.ndarray, left: np.ndarray, right: np.ndarray, band: tuple[float, float], points: int = 400
) -> tuple[np.ndarray, np.ndarray]:
    """|left (jωI − F)⁻¹ right|₂ per row on a grid of the band (endpoints included), shape
    (points, rows), and the grid."""
    omegas = np.linspace(band[0], band[1], points)
    n = F.shape[0]
    gains = np.array([np.linalg.norm(left @ np.linalg.solve(1j * w * np.eye(n) - F, right), axis=1) for w in omegas])
    return gains, omegas


def centred_bounds(
    F: np.ndarray, C: np.ndarray, RE: np.ndarray, environment: DeclaredEnvironment, sample_time: float
) -> np.ndarray:
    """Bound on |r_i(t) − m̂_i| for t ≥ t₂, every b of the declared class and e(0) = 0, where m̂_i
    is the mean of the samples r_i(t_k), t₁ ≤ t_k < t₂ (K samples, τ = ``sample_time``):

        A max_ω |H_i,f(jω)|(1 + λ_f(ω)) + N max_ω |H_i,n(jω)|(1 + λ_n(ω))
            + 2 A κ ∫₀^∞ s |h_i,f(s)| ds + 2 B ∫_{t₁}^∞ |h_i(s)| ds + 2 ε_d ∫₀^∞ |h_i(s)| ds

    with A, N the wave force and moment sums, ε_d the model error at rest, B = current +
    hypot(A, N) + ε_d the bound on |b + d|, and
    λ(ω) ≤ 1 the share of a wave's amplitude left in the window's mean: (1/K + κτ)/sin(ωτ/2)
    for the turning force (summation by parts), 1/(K sin(ωτ/2)) for the moment. The terms are
    the wave's response now and in the mean, the turning direction's departure from a sinusoid
    (|d(t − s) − d(t)| ≤ κ s), the start-up transients (the convolution from 0 instead of −∞),
    and the model error now and in the mean. The current's response g_i b_c is in both r_i and
    m̂_i to within the transient: it cancels."""
    env = environment
    t1, t2 = env.learning
    K = max(1, int(round((t2 - t1) / sample_time)))
    low, high = env.band
    force, moment = RE[:, list(FORCE)], RE[:, list(MOMENT)]
    kappa = env.turn_rate
    gf, omegas = band_gains(F, C, force, (low, high))
    gn, _ = band_gains(F, C, moment, (low, high))
    s_half = np.sin(np.minimum(omegas * sample_time / 2.0, np.pi / 2))[:, None]
    share_f = np.minimum(1.0, (1.0 / K + kappa * sample_time) / s_half)
    share_n = np.minimum(1.0, (1.0 / K) / s_half)
    waves = env.wave_force * (gf * (1 + share_f)).max(axis=0) + env.wave_moment * (gn * (1 + share_n)).max(axis=0)
    turning = 2.0 * env.wave_force * kappa * _integral(F, C, force, weight=lambda s: s)
    tails = 2.0 * env.bound * _integral(F, C, RE, start=t1)
    model = 2.0 * env.model_error * _integral(F, C, RE)
    return waves + turning + tails + model


class InertialAllowance:
    """The part of the model error that grows with the motion: |d(t)|₂ ≤ ρ a(t), a(t) = |E⁺ ẏ(t)|
    the inertial force (M ν̇ for the ship: the design model's errors, the sampling of y and the
    plant's effects first-order in ψ, scale with the accelerations, which a fault makes large).
    Its response in r_i is at most ρ ∫ |h_i(s)| a(t − s) ds ≤ ρ Σ_k |c_ik| |(R E)_k| q_k(t) for
    diagonal F, q_k the first-order filter of a with pole f_k; a is the rate over each sample,
    (y_k − y_{k−1})/τ, held."""

    def __init__(
        self, observers: Sequence[COFDObserver], C: np.ndarray, E: np.ndarray, ratio: float, sample_time: float
    ) -> None:
        poles = [np.diag(o.F) for o in observers]
        if any(not np.allclose(o.F, np.diag(f)) for o, f in zip(observers, poles)):
            raise ValueError("the inertial allowance needs a diagonal F")
        self.decay = [np.exp(f * sample_time) for f in poles]
        self.step = [(1.0 - d) / -f for d, f in zip(self.decay, poles)]
        self.weights = [ratio * np.abs(C) * np.linalg.norm(o.R @ E, axis=1) for o in observers]
        self.rate = np.linalg.pinv(E) / sample_time
        self.q = [np.zeros(len(f)) for f in poles]
        self.y_prev: np.ndarray | None = None

    def __call__(self, y: np.ndarray) -> np.ndarray:
        """The allowance of every residual component (observers, components) after sample y."""
        a = 0.0 if self.y_prev is None else float(np.linalg.norm(self.rate @ (y - self.y_prev)))
        self.y_prev = y
        self.q = [d * q + g * a for q, d, g in zip(self.q, self.decay, self.step)]
        return np.array([w @ q for w, q in zip(self.weights, self.q)])


class ResidualTest:
    """Which residual components fire, tick by tick: |r_i| > thr_i with the flat thresholds (the
    paper's class |b| ≤ ε) until the learning window [t₁, t₂) is over, then |r_i − m̂_i| > thr'_i
    with the declared environment's (``centred_bounds``), m̂_i the mean of r_i's samples in the
    window; both plus the inertial allowance of the model error (and its mean over the window)
    when there is one. Without ``centred`` (no environment declared) the flat thresholds hold
    throughout."""

    def __init__(
        self,
        flat: np.ndarray,
        centred: np.ndarray | None,
        window: tuple[float, ...],
        sample_time: float,
        allowance: InertialAllowance | None = None,
    ) -> None:
        self.flat, self.centred, self.allowance = flat, centred, allowance
        self.start, self.end = (edge - sample_time / 2.0 for edge in window)
        self.total = np.zeros((2, *flat.shape))
        self.count = 0
        self.mean: np.ndarray | None = None

    def __call__(self, t: float, r: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(r − m̂, thresholds) at time t (s since the first sample) and output y; m̂ = 0 until it
        is learned."""
        extra = self.allowance(y) if self.allowance is not None else np.zeros_like(self.flat)
        if self.centred is None:
            return r, self.flat + extra
        if self.mean is None and t >= self.end:
            self.mean = self.total / max(self.count, 1)
        if self.mean is None:
            if t >= self.start:
                self.total += (r, extra)
                self.count += 1
            return r, self.flat + extra
        return r - self.mean[0], self.centred + extra + self.mean[1]


def residual_test(
    observers: Sequence[COFDObserver],
    C: np.ndarray,
    E: np.ndarray,
    params: DeclaredEnvironment,
    flat: np.ndarray,
    centred: np.ndarray | None,
    sample_time: float,
    margin: float,
) -> ResidualTest:
    """The residual test of kind ``cofd`` (``params``: its ``COFDParams``, the declared environment
    checked by ``cofd.check_declared``): the flat thresholds ``flat`` throughout, or, with a declared
    environment, the ``centred`` ones (``centred_thresholds``) once the learning window is over,
    and ``margin`` × the inertial allowance."""
    if not params.declared:
        return ResidualTest(flat, None, params.learning, sample_time)
    ell = flat.shape[1]
    allowance = InertialAllowance(observers, C[:ell], E, margin * params.model_error_ratio, sample_time)
    return ResidualTest(flat, centred, params.learning, sample_time, allowance)


def centred_thresholds(
    observers: Sequence[COFDObserver],
    C: np.ndarray,
    E: np.ndarray,
    params: DeclaredEnvironment,
    sample_time: float,
    ell: int,
    margin: float,
) -> np.ndarray | None:
    """``margin`` × ``centred_bounds`` of each observer's first ``ell`` components (one row per
    observer), or None without a declared environment."""
    if not params.declared:
        return None
    centred = np.array([centred_bounds(o.F, C[:ell], o.R @ E, params, sample_time) for o in observers])
    return margin * centred
