"""Discrete-time Kalman filter: the reference estimator on the same (biased) outputs.

Standard predict/update recursion for x⁺ = A x + B u + w, y = C x + D u + v with
w ~ N(0, Q), v ~ N(0, R), Q = diag(process_std²), R = diag(measurement_std²). At tick k the filter
updates with the readings that arrived (rows of missing ones are skipped), returns the filtered
estimate x̂_{k|k}, then predicts x̂_{k+1|k}. The covariance update uses the Joseph form, which
stays symmetric positive semidefinite in floating point.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from estimators.base import Estimate, Estimator, ParameterError, initial_state
from estimators.batched import BatchEstimate, DeviationBatch, mv
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
        self._identity = np.eye(model.n)
        self._At = model.A.T

    def _step(self, dy: np.ndarray, du: np.ndarray) -> Estimate:
        A, B, C, D = self.model.A, self.model.B, self.model.C, self.model.D
        x, P = self.x_hat, self.P
        missing = np.isnan(dy)
        if not missing.any():  # every reading arrived: the whole C and R (the same numbers as below, no copies)
            x, P = self._update(x, P, C, self.R, dy - C @ x - D @ du)
        elif not missing.all():
            rows = ~missing
            x, P = self._update(x, P, C[rows], self.R[np.ix_(rows, rows)], dy[rows] - C[rows] @ x - D[rows] @ du)
        self.x_hat = A @ x + B @ du
        self.P = A @ P @ self._At + self.Q
        return Estimate(x)

    def _update(
        self, x: np.ndarray, P: np.ndarray, Ck: np.ndarray, Rk: np.ndarray, innovation: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        CkP = Ck @ P
        S = CkP @ Ck.T + Rk
        K = np.linalg.solve(S, CkP).T  # P Cᵀ S⁻¹ (S and P symmetric)
        I_KC = self._identity - K @ Ck
        return x + K @ innovation, I_KC @ P @ I_KC.T + K @ Rk @ K.T

    @classmethod
    def batched(cls, instances: Sequence[KalmanFilter]) -> _KalmanBatch:
        return _KalmanBatch(instances)


class _KalmanBatch(DeviationBatch):
    """K filters of one design: x̂ (K, n) and P (K, n, n), updated and predicted in NumPy's stacked
    kernels; a run with a missing reading takes its own filter's step (fewer rows of C)."""

    def __init__(self, instances: Sequence[KalmanFilter]) -> None:
        super().__init__(instances)
        self.filters = list(instances)
        first = instances[0]
        self.R, self.Q, self._identity, self._At = first.R, first.Q, first._identity, first._At
        self.x = np.stack([e.x_hat for e in instances])
        self.P = np.stack([e.P for e in instances])

    def _step(self, dy: np.ndarray, du: np.ndarray) -> BatchEstimate:
        A, B, C, D = self.model.A, self.model.B, self.model.C, self.model.D
        missing = np.isnan(dy)
        whole = ~missing.any(axis=1)
        x, P = self.x, self.P
        if whole.all():
            x, P = self._update(x, P, dy - mv(C, x) - mv(D, du))
            own: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        else:  # rows with every reading updated here; with some, each by its own filter's step (fewer rows of C)
            x, P = x.copy(), P.copy()
            rows = np.flatnonzero(whole)
            if rows.size:
                x[rows], P[rows] = self._update(x[rows], P[rows], dy[rows] - mv(C, x[rows]) - mv(D, du[rows]))
            own = {}
            for r in map(int, np.flatnonzero(~whole & ~missing.all(axis=1))):
                single = self.filters[r]
                single.x_hat, single.P = self.x[r].copy(), self.P[r].copy()
                x[r] = single._step(dy[r], du[r]).x
                own[r] = single.x_hat, single.P  # already predicted
        x_next = mv(A, x) + mv(B, du)
        P_next = A @ P @ self._At + self.Q
        for row, (predicted_x, predicted_P) in own.items():
            x_next[row], P_next[row] = predicted_x, predicted_P
        self.x, self.P = x_next, P_next
        return BatchEstimate(x, {})

    def _update(self, x: np.ndarray, P: np.ndarray, innovation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``KalmanFilter._update`` with the whole C and R, for K runs."""
        C, R = self.model.C, self.R
        CkP = C @ P
        S = CkP @ C.T + R
        K = np.linalg.solve(S, CkP).swapaxes(-1, -2)
        I_KC = self._identity - K @ C
        return x + mv(K, innovation), I_KC @ P @ I_KC.swapaxes(-1, -2) + K @ R @ K.swapaxes(-1, -2)
