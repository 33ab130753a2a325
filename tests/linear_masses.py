"""The coupled masses of TAC 2024 (Table I) as a discrete linear model: the tests' and the
benchmarks' workload, the same MJCF parameters as the plant (``mjcf.masses``), exactly discretized."""

from __future__ import annotations

import numpy as np

from estimators import LinearModel
from estimators.design import zoh_discretize
from mjcf import masses

#: The sensors of the paper's Example 1: x1, x2 and x1 − x2 (p = 3).
SENSORS = ("x1", "x2", "x1_minus_x2")


def masses_model(sensors: tuple[str, ...] | list[str] = SENSORS, sample_time: float = 0.01) -> LinearModel:
    """x⁺ = A x + B force, y = C x for ``sensors``, zero-order hold over ``sample_time``."""
    A, B = zoh_discretize(*masses.continuous_model(), sample_time)
    C = masses.output_matrix(sensors)
    states, inputs = ("x1", "x2", "v1", "v2"), ("force",)
    return LinearModel(A, B, C, np.zeros((len(sensors), 1)), sample_time, states, inputs, tuple(sensors))
