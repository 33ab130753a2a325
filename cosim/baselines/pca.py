"""PCA monitoring of the readings: Hotelling's T² and the squared prediction error (the faults track).

Fitted on normal ticks' readings X (N × p), standardized z = (y − μ) / σ: the covariance's
eigenvectors P (p × a) and eigenvalues λ₁ ≥ … ≥ λ_a of the a principal components that explain
``variance`` of it, at most p − 1 so that the SPE has a subspace to live in (MacGregor & Kourti,
Control Eng. Practice 1995; Qin, J. Chemometrics 2003):

    T² = Σᵢ (pᵢᵀ z)² / λᵢ         (the distance within the principal subspace)
    SPE = ‖(I − P Pᵀ) z‖²          (the residual outside it: a broken correlation between sensors)

Each statistic's limit is its ``quantile`` over the validation split's normal ticks (no
distribution assumed). A reading that did not come makes both infinite (over the limit).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cosim.api import Diagnostic, DiagnosticKind
from cosim.baselines.monitor import Monitor

T2 = Diagnostic("t2", "", "Hotelling's T² of the readings", 1e6, 1e-3, DiagnosticKind.RESIDUAL_NORM)
SPE = Diagnostic("spe", "", "squared prediction error (Q) of the readings", 1e6, 1e-3, DiagnosticKind.RESIDUAL_NORM)


def fit(readings: np.ndarray, variance: float = 0.95) -> dict[str, Any]:
    """The PCA model of normal readings (rows: ticks; no NaN): mean, std, loadings, eigenvalues."""
    mean = readings.mean(axis=0)
    std = readings.std(axis=0, ddof=1)
    std = np.where(std > 0, std, 1.0)
    z = (readings - mean) / std
    _, s, vt = np.linalg.svd(z, full_matrices=False)
    eigenvalues = s**2 / (len(z) - 1)
    explained = np.cumsum(eigenvalues) / eigenvalues.sum()
    a = min(int(np.searchsorted(explained, variance) + 1), max(1, len(mean) - 1))  # leave a residual subspace
    return {
        "mean": mean.tolist(),
        "std": std.tolist(),
        "loadings": vt[:a].T.tolist(),
        "eigenvalues": eigenvalues[:a].tolist(),
        "explained": float(explained[a - 1]),
    }


def statistics(fitted: dict[str, Any], readings: np.ndarray) -> dict[str, np.ndarray]:
    """T² and SPE of readings (rows: ticks) under a fitted model; inf where a reading is missing."""
    z = (readings - np.asarray(fitted["mean"])) / np.asarray(fitted["std"])
    p = np.asarray(fitted["loadings"])
    scores = z @ p
    t2 = (scores**2 / np.asarray(fitted["eigenvalues"])).sum(axis=1)
    spe = ((z - scores @ p.T) ** 2).sum(axis=1)
    missing = np.isnan(readings).any(axis=1)
    return {"t2": np.where(missing, np.inf, t2), "spe": np.where(missing, np.inf, spe)}


class PcaMonitor(Monitor):
    """PCA on the readings, alarm on T² or SPE over its limit (``cosim.baselines.pca``)."""

    kind = "pca-monitor"
    kind_of_file = "pca"
    STATISTICS = (T2, SPE)

    def statistics(self, y: np.ndarray) -> dict[str, float]:
        assert self.fitted is not None
        return {name: float(value[0]) for name, value in statistics(self.fitted, y[None, :]).items()}
