"""State estimators: pure algorithms on linear models (numpy/scipy only, no I/O).

Registry keyed by kind: ``create(kind, model, params)`` builds one from a plain parameter dict.
"""

from __future__ import annotations

from typing import Any

from estimators.adaptive import AdaptivePseudoinverseObserver, InjectionObserver
from estimators.base import Diagnostic, Estimate, Estimator, ParameterError
from estimators.cofd import COFDDiagnosis
from estimators.continuous import ContinuousAdaptiveObserver
from estimators.kalman import KalmanFilter
from estimators.model import LinearModel
from estimators.pseudoinverse import PseudoinverseObserver
from estimators.reconciliation import (
    LftUioReconciliator,
    LpvUioReconciliator,
    NoReconciliation,
)
from estimators.uio import UnknownInputObserver

ESTIMATORS: dict[str, type[Estimator]] = {cls.kind: cls for cls in (
    PseudoinverseObserver, AdaptivePseudoinverseObserver, InjectionObserver, ContinuousAdaptiveObserver, KalmanFilter,
    UnknownInputObserver, LpvUioReconciliator, LftUioReconciliator, NoReconciliation, COFDDiagnosis,
)}


def create(kind: str, model: LinearModel, params: dict[str, Any] | None = None, sample_time: float | None = None) -> Estimator:
    """The estimator of the given kind for ``model`` (continuous-time kinds also need the sample
    time); unknown kinds and bad parameters raise ParameterError naming the culprit."""
    if kind not in ESTIMATORS:
        raise ParameterError("kind", f"unknown estimator {kind!r} (known: {', '.join(sorted(ESTIMATORS))})")
    return ESTIMATORS[kind].from_params(model, params, sample_time)


__all__ = ["ESTIMATORS", "Diagnostic", "Estimate", "Estimator", "LinearModel", "ParameterError", "create"]
