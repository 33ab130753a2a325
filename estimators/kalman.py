"""Discrete-time Kalman filter: the reference estimator on the same (biased) outputs.

Standard predict/update recursion for x⁺ = A x + B u + w, y = C x + D u + v with
w ~ N(0, Q), v ~ N(0, R), Q = diag(process_std²), R = diag(measurement_std²). At tick k the filter
updates with the readings that arrived (rows of missing ones are skipped), returns the filtered
estimate x̂_{k|k}, then predicts x̂_{k+1|k}. The covariance update uses the Joseph form, which
stays symmetric positive semidefinite in floating point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.base import Estimate, Estimator, ParameterError, initial_state
from estimators.model import LinearModel


@dataclass(frozen=True)
class KalmanParams:
    measurement_std: float | tuple[float, ...] = 1e-3
    """Standard deviation of each output's noise (one value, or one per output)."""
    process_std: float | tuple[float, ...] = 1e-4
    """Standard deviation of the process noise on each state per step (one value, or one per state)."""
    initial_std: float | tuple[float, ...] = 1.0
    """Standard deviation of the initial estimate's error (one value, or one per state)."""
    x0: tuple[float, ...] | None = None
    """Initial estimate x̂_0 (absolute); None starts at the operating point."""


def _diagonal(values: float | tuple[float, ...], size: int, name: str, labels: tuple[str, ...]) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    if array.ndim == 0:
        array = np.full(size, float(array))
    if array.shape != (size,):
        raise ParameterError(name, f"expected one value or {size} ({', '.join(labels)}), got {array.size}")
    if not np.all(np.isfinite(array)) or np.any(array < 0):
        raise ParameterError(name, "standard deviations must be finite and non-negative")
    return np.diag(array**2)


class KalmanFilter(Estimator):
    kind = "kalman"
    Params = KalmanParams

    def __init__(self, model: LinearModel, params: KalmanParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        self.Q = _diagonal(params.process_std, model.n, "process_std", model.states)
        self.R = _diagonal(params.measurement_std, model.p, "measurement_std", model.outputs)
        if np.any(np.diag(self.R) == 0):
            raise ParameterError("measurement_std", "must be positive (R must be invertible)")
        self.P = _diagonal(params.initial_std, model.n, "initial_std", model.states)
        self.x_hat = initial_state(model, params.x0)

    def _step(self, dy: np.ndarray, du: np.ndarray) -> Estimate:
        A, B, C, D = self.model.A, self.model.B, self.model.C, self.model.D
        rows = ~np.isnan(dy)
        x, P = self.x_hat, self.P
        if rows.any():
            Ck, Rk = C[rows], self.R[np.ix_(rows, rows)]
            innovation = dy[rows] - Ck @ x - D[rows] @ du
            S = Ck @ P @ Ck.T + Rk
            K = np.linalg.solve(S, Ck @ P).T  # P Cᵀ S⁻¹ (S and P symmetric)
            x = x + K @ innovation
            I_KC = np.eye(self.model.n) - K @ Ck
            P = I_KC @ P @ I_KC.T + K @ Rk @ K.T
        self.x_hat = A @ x + B @ du
        self.P = A @ P @ A.T + self.Q
        return Estimate(x)
