"""State estimators and controllers: pure algorithms on linear models (numpy/scipy only, no I/O).

Registries keyed by kind: ``create(kind, model, params)`` builds an estimator from a plain
parameter dict; ``CONTROLLERS`` (``estimators.controller``) holds the controller kinds.
"""

from __future__ import annotations

from typing import Any

from estimators.base import Diagnostic, Estimate, Estimator, ParameterError, Registry
from estimators.controller import CONTROLLERS, PidController
from estimators.model import LinearModel

#: Estimator kinds; each kind's module is imported when the kind is first looked up.
ESTIMATORS: Registry = Registry(
    {
        "pseudoinverse": "estimators.pseudoinverse:PseudoinverseObserver",
        "adaptive": "estimators.adaptive:AdaptivePseudoinverseObserver",
        "injection": "estimators.adaptive:InjectionObserver",
        "adaptive-ct": "estimators.continuous:ContinuousAdaptiveObserver",
        "kalman": "estimators.kalman:KalmanFilter",
        "uio": "estimators.uio:UnknownInputObserver",
        "lpv-uio-sr": "estimators.reconciliation:LpvUioReconciliator",
        "lft-uio-sr": "estimators.reconciliation:LftUioReconciliator",
        "no-reconciliation": "estimators.reconciliation:NoReconciliation",
        "cofd": "estimators.cofd:COFDDiagnosis",
    }
)


def __getattr__(name: str) -> Any:
    if name == "ThrustAllocationController":  # imported on first use (SciPy's optimizer)
        from estimators.allocation import ThrustAllocationController

        return ThrustAllocationController
    raise AttributeError(f"module 'estimators' has no attribute {name!r}")


def create(
    kind: str, model: LinearModel, params: dict[str, Any] | None = None, sample_time: float | None = None
) -> Estimator:
    """The estimator of the given kind for ``model`` (continuous-time kinds also need the sample
    time); unknown kinds and bad parameters raise ParameterError naming the culprit."""
    if kind not in ESTIMATORS:
        raise ParameterError("kind", f"unknown estimator {kind!r} (known: {', '.join(sorted(ESTIMATORS))})")
    cls: type[Estimator] = ESTIMATORS[kind]
    return cls.from_params(model, params, sample_time)


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
