"""State estimators and controllers: pure algorithms on linear models (numpy/scipy only, no I/O).

Registries keyed by kind: ``create(kind, model, params)`` builds an estimator from a plain
parameter dict; ``CONTROLLERS`` (``estimators.controller``) holds the controller kinds.
"""

from __future__ import annotations

from typing import Any

from estimators.adaptive import AdaptivePseudoinverseObserver, InjectionObserver
from estimators.allocation import ThrustAllocationController
from estimators.base import Diagnostic, Estimate, Estimator, ParameterError
from estimators.cofd import COFDDiagnosis
from estimators.continuous import ContinuousAdaptiveObserver
from estimators.controller import CONTROLLERS, PidController
from estimators.kalman import KalmanFilter
from estimators.model import LinearModel
from estimators.pseudoinverse import PseudoinverseObserver
from estimators.reconciliation import LftUioReconciliator, LpvUioReconciliator, NoReconciliation
from estimators.uio import UnknownInputObserver

ESTIMATORS: dict[str, type[Estimator]] = {
    cls.kind: cls
    for cls in (
        PseudoinverseObserver,
        AdaptivePseudoinverseObserver,
        InjectionObserver,
        ContinuousAdaptiveObserver,
        KalmanFilter,
        UnknownInputObserver,
        LpvUioReconciliator,
        LftUioReconciliator,
        NoReconciliation,
        COFDDiagnosis,
    )
}


def create(
    kind: str, model: LinearModel, params: dict[str, Any] | None = None, sample_time: float | None = None
) -> Estimator:
    """The estimator of the given kind for ``model`` (continuous-time kinds also need the sample
    time); unknown kinds and bad parameters raise ParameterError naming the culprit."""
    if kind not in ESTIMATORS:
        raise ParameterError("kind", f"unknown estimator {kind!r} (known: {', '.join(sorted(ESTIMATORS))})")
    return ESTIMATORS[kind].from_params(model, params, sample_time)


# Importing the controller kinds registers them in CONTROLLERS.
__all__ = [
    "CONTROLLERS",
    "ESTIMATORS",
    "PidController",
    "ThrustAllocationController",
    "Diagnostic",
    "Estimate",
    "Estimator",
    "LinearModel",
    "ParameterError",
    "create",
]
