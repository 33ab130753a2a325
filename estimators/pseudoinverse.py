"""Luenberger observer with a static weighted pseudoinverse of redundant outputs.

The observer (13)–(14) of Cristofaro & Zaccarian, IEEE TAC 2024, with the selector s held constant:

    x̂⁺ = A x̂ + B u + L Π(s) (y − C x̂),   Π(s) = (Yᵀ diag(s) Y)⁻¹ Yᵀ diag(s),

where C = Y H (eq. (2), Example 1) and L places the spectrum of A − L H. With the uniform weights
s = 𝟙/√p it is the paper's baseline "observer based on a constant pseudoinverse with uniform
weights" (Sec. VII-A). Under a constant bias φ its error obeys e⁺ = (A − L H) e − L Π(s) φ
(eq. (19)–(20), with the sign corrected: see docs/errata.md) and settles at
e = −(I − A + L H)⁻¹ L Π(s) φ, which is not zero unless Π(s) φ = 0.

Missing readings (frames not received) get weight 0 for that tick, provided the remaining weights
keep R(s) invertible; otherwise the tick is an open-loop prediction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimators.base import Estimate, Estimator, ParameterError, initial_state
from estimators.batched import BatchEstimate, DeviationBatch, mv
from estimators.design import observer_gain, output_factorization, weighted_pseudoinverse
from estimators.model import LinearModel


@dataclass(frozen=True)
class PseudoinverseParams:
    poles: tuple[float, ...] = (0.75, 0.8, 0.85, 0.9)
    """Spectrum of A − L H (TAC 2024, Sec. VII-A: {0.75, 0.8, 0.85, 0.9})."""
    weights: tuple[float, ...] | None = None
    """The selector s; None gives the uniform weights 𝟙/√p. Scale does not matter (Π(μs) = Π(s))."""
    x0: tuple[float, ...] | None = None
    """Initial estimate x̂_0 (absolute); None starts at the operating point."""
    min_det: float = 1e-9
    """|det R(s)| below which a tick's weights are deemed singular (the set S_ε of eq. (15))."""
    gain: tuple[tuple[float, ...], ...] | None = None
    """The observer gain L (n × q rows) placing ``poles``, where it is known: the runner hands its
    design to the node processes this way. None: placed from ``poles``."""


class PseudoinverseObserver(Estimator):
    """Observer (13) with a constant weighted pseudoinverse (14)."""

    kind = "pseudoinverse"
    Params = PseudoinverseParams

    def __init__(self, model: LinearModel, params: PseudoinverseParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        self.Y, self.H = output_factorization(model.C)
        q, p = self.H.shape[0], model.p
        if q >= p:
            raise ParameterError(
                "model", f"outputs are not redundant: rank(C) = {q} is not below p = {p} (TAC 2024, Assumption 1.1)"
            )
        weights = np.full(p, 1.0 / np.sqrt(p)) if params.weights is None else np.asarray(params.weights, dtype=float)
        if weights.shape != (p,):
            raise ParameterError(
                "weights", f"expected {p} weights (one per output: {', '.join(model.outputs)}), got {weights.size}"
            )
        self.weights = weights / np.linalg.norm(weights)
        if abs(np.linalg.det(self.Y.T @ (self.weights[:, None] * self.Y))) < params.min_det:
            raise ParameterError("weights", "R(s) = Yᵀ diag(s) Y is singular for these weights (eq. (14))")
        if np.any(np.abs(np.asarray(params.poles)) >= 1.0):
            raise ParameterError(
                "poles", f"{list(params.poles)}: every pole must lie inside the unit circle, so that A − L H is Schur"
            )
        if params.gain is not None:
            self.L = np.array(params.gain, dtype=float)
            if self.L.shape != (model.n, q):
                raise ParameterError("gain", f"expected L of shape ({model.n}, {q}), got {self.L.shape}")
        else:
            try:
                # contiguous, as the gain a node is handed (the placement returns a strided view, and
                # numpy's products may round differently in the last bit for another layout)
                self.L = np.ascontiguousarray(observer_gain(model.A, self.H, params.poles))
            except ValueError as error:
                raise ParameterError("poles", str(error)) from None
        self.Pi = weighted_pseudoinverse(self.Y, self.weights)
        self.x_hat = initial_state(model, params.x0)

    def node_params(self) -> dict[str, Any]:
        return {**self.design_params(), "gain": self.L.tolist()}

    def _allocation(self, available: np.ndarray) -> np.ndarray | None:
        """Π(s) for this tick: missing readings get weight 0; None if R(s) becomes singular."""
        if available.all():
            return self.Pi
        s = np.where(available, self.weights, 0.0)
        if abs(np.linalg.det(self.Y.T @ (s[:, None] * self.Y))) < self.params.min_det:
            return None
        return weighted_pseudoinverse(self.Y, s)

    def _step(self, dy: np.ndarray, du: np.ndarray) -> Estimate:
        A, B, C = self.model.A, self.model.B, self.model.C
        x_k = self.x_hat
        available = ~np.isnan(dy)
        Pi = self._allocation(available)
        correction = np.zeros(self.model.n)
        if Pi is not None:
            innovation = np.where(available, dy - C @ x_k, 0.0)
            correction = self.L @ (Pi @ innovation)
        self.x_hat = A @ x_k + B @ du + correction  # eq. (13)
        return Estimate(x_k.copy())

    def bias_effect(self, diagnostics: dict[str, float], phi: np.ndarray) -> np.ndarray:
        """Π(s) φ: the constant offset the bias adds to the injection (eq. (19))."""
        return self.Pi @ phi

    @classmethod
    def batched(cls, instances: Sequence[PseudoinverseObserver]) -> _PseudoinverseBatch:
        return _PseudoinverseBatch(instances)


class _PseudoinverseBatch(DeviationBatch):
    """K observers (13) of one design: x̂ of shape (K, n); a run with a missing reading takes its
    own observer's step (its weights change, ``_allocation``)."""

    def __init__(self, instances: Sequence[PseudoinverseObserver]) -> None:
        super().__init__(instances)
        self.observers = list(instances)
        first = instances[0]
        self.L, self.Pi = first.L, first.Pi
        self.x = np.stack([e.x_hat for e in instances])

    def _step(self, dy: np.ndarray, du: np.ndarray) -> BatchEstimate:
        A, B, C = self.model.A, self.model.B, self.model.C
        x_k = self.x
        whole = ~np.isnan(dy).any(axis=1)
        correction = mv(self.L, mv(self.Pi, dy - mv(C, x_k)))  # np.where(available, ., 0) is the identity here
        x_next = mv(A, x_k) + mv(B, du) + correction  # eq. (13)
        if not whole.all():
            rows = np.flatnonzero(~whole)
            # each the observer's own step; the estimate is x_k either way
            self._each(rows, dy, du, lambda e, r: setattr(e, "x_hat", x_k[r].copy()), lambda e, r: None)
            x_next[rows] = np.stack([self.observers[r].x_hat for r in rows])
        self.x = x_next
        return BatchEstimate(x_k.copy(), {})
