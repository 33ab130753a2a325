"""State estimators: pure algorithms on linear models (numpy/scipy only, no I/O).

Registry keyed by kind: ``create(kind, model, params)`` builds one from a plain parameter dict.
"""

from __future__ import annotations

from typing import Any

from estimators.base import Estimate, Estimator, ParameterError
from estimators.kalman import KalmanFilter
from estimators.model import LinearModel
from estimators.pseudoinverse import PseudoinverseObserver

ESTIMATORS: dict[str, type[Estimator]] = {cls.kind: cls for cls in (PseudoinverseObserver, KalmanFilter)}


def create(kind: str, model: LinearModel, params: dict[str, Any] | None = None) -> Estimator:
    """The estimator of the given kind for ``model``; unknown kinds and bad parameters raise
    ParameterError naming the culprit."""
    if kind not in ESTIMATORS:
        raise ParameterError("kind", f"unknown estimator {kind!r} (known: {', '.join(sorted(ESTIMATORS))})")
    return ESTIMATORS[kind].from_params(model, params)


__all__ = ["ESTIMATORS", "Estimate", "Estimator", "LinearModel", "ParameterError", "create"]
