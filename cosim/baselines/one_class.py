"""A one-class model of every reading id's payload statistics: its value and its change in a tick
(the attacks track).

The features of tick k are, per reading, its standardized value zₖ = (yₖ − μ) / σ and its change
Δzₖ = zₖ − zₖ₋₁; normal ticks' features f (N × 2p) make a Gaussian (mean m, covariance C, shrunk
towards its diagonal by ``shrinkage`` to stay invertible: two sensors that measure the same
coordinate make C nearly singular, which is what makes a forged one stand out). The score is the
Mahalanobis distance d² = (f − m)ᵀ C⁻¹ (f − m) (an elliptic envelope: Rousseeuw & Van Driessen 1999
without the robust fit, the training ticks being normal). A reading that did not come, or came
twice (its receivers took neither, which a fabricated frame beside the genuine one causes) has no
value: its score is infinite. The limit is the score's ``quantile`` over the validation split's
normal ticks.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cosim.api import Diagnostic, DiagnosticKind
from cosim.baselines.monitor import Monitor

SCORE = Diagnostic(
    "d2", "", "Mahalanobis distance² of the readings' values and changes", 1e6, 1e-3, DiagnosticKind.RESIDUAL_NORM
)


def features(fitted: dict[str, Any], readings: np.ndarray, previous: np.ndarray | None = None) -> np.ndarray:
    """[z, Δz] of consecutive readings (rows: ticks of one run; ``previous``: the tick before the first)."""
    z = (readings - np.asarray(fitted["mean"])) / np.asarray(fitted["std"])
    before = np.vstack([z[:1] * np.nan if previous is None else previous[None, :], z[:-1]])
    return np.hstack([z, z - before])


def fit(runs: list[np.ndarray], shrinkage: float = 1e-3) -> dict[str, Any]:
    """The model of normal readings, one array per run (rows: consecutive ticks; no NaN)."""
    stacked = np.vstack(runs)
    mean = stacked.mean(axis=0)
    std = stacked.std(axis=0, ddof=1)
    model: dict[str, Any] = {"mean": mean.tolist(), "std": np.where(std > 0, std, 1.0).tolist()}
    f = np.vstack([features(model, run)[1:] for run in runs])
    center = f.mean(axis=0)
    covariance = np.cov(f, rowvar=False)
    covariance = (1 - shrinkage) * covariance + shrinkage * np.diag(np.diag(covariance))
    model |= {"center": center.tolist(), "precision": np.linalg.inv(covariance).tolist()}
    return model


def scores(fitted: dict[str, Any], f: np.ndarray) -> np.ndarray:
    """d² of feature rows; inf where a feature is missing."""
    d = f - np.asarray(fitted["center"])
    d2 = np.einsum("ij,jk,ik->i", np.nan_to_num(d), np.asarray(fitted["precision"]), np.nan_to_num(d))
    return np.where(np.isnan(f).any(axis=1), np.inf, d2)


class OneClassMonitor(Monitor):
    """A one-class Gaussian model of the readings' values and changes (``cosim.baselines.one_class``)."""

    kind = "one-class-monitor"
    kind_of_file = "one_class"
    STATISTICS = (SCORE,)

    def setup(self, fitted: dict[str, Any]) -> None:
        self._previous: np.ndarray | None = None

    def statistics(self, y: np.ndarray) -> dict[str, float]:
        assert self.fitted is not None
        z = (y - self.mean) / self.std
        f = np.concatenate([z, z - (self._previous if self._previous is not None else np.full_like(z, np.nan))])
        self._previous = z
        return {SCORE.name: float(scores(self.fitted, f[None, :])[0])}
