"""State estimators and controllers: pure algorithms on linear models (numpy/scipy only, no I/O).

``ESTIMATORS`` and ``CONTROLLERS`` (``estimators.controller``) are the kinds by name (``kinds``:
built in, a module path, or a plugin's entry point); ``create(kind, model, params)`` builds an
estimator from a plain parameter dict.
"""

from __future__ import annotations

from typing import Any

from cosim.kinds import KindError, Kinds
from estimators.base import Estimate, Estimator, ParameterError
from estimators.controller import CONTROLLERS, PidController
from estimators.diagnostics import Diagnostic, DiagnosticKind
from estimators.model import LinearModel

#: Estimator kinds; each built-in kind's module is imported when the kind is first looked up.
ESTIMATORS: Kinds[type[Estimator]] = Kinds(
    "estimator",
    "cosim.estimators",
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
    },
    Estimator,
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
    try:
        cls = ESTIMATORS[kind]
    except KindError as error:
        raise ParameterError("kind", str(error)) from None
    return cls.from_params(model, params, sample_time)


__all__ = [
    "CONTROLLERS",
    "ESTIMATORS",
    "PidController",
    "ThrustAllocationController",
    "Diagnostic",
    "DiagnosticKind",
    "Estimate",
    "Estimator",
    "LinearModel",
    "ParameterError",
    "create",
]
