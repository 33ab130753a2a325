"""The paper's three-tank model of IJC 2018, eq. (58)-(59), as printed, for the tests of sensor
reconciliation (tests/test_reconciliation.py, test_model_window.py, test_gain_identification.py,
test_gain_identification_shortcuts.py): its matrices, its LinearModel, the LFT design of Theorem 1
on its gain box (made once per process) and a window of its readings."""

from __future__ import annotations

import functools

import numpy as np

from estimators.lft_design import lft_uio_design
from estimators.lmi import SensorFaultModel
from estimators.model import LinearModel
from mjcf.three_tank import PAPER_A, PAPER_B, PAPER_C, PAPER_E

# IJC 2018, eq. (59), as printed
A, B, C, E = PAPER_A, PAPER_B, PAPER_C, PAPER_E
F = np.ones((4, 1))
HZ = [1 / 3, 1 / 3, 0.0, 1 / 3]
PAPER = SensorFaultModel(A, B, E, C, F)
LOW, HIGH = np.full(4, 0.5), np.ones(4)


def paper_model() -> LinearModel:
    return LinearModel(
        A,
        B,
        C,
        np.zeros((4, 2)),
        1.0,
        ("h1", "h2", "h3"),
        ("Q1", "Q2"),
        ("y1", "y2", "y3", "y4"),
        E=E,
        disturbances=("v",),
    )


@functools.cache
def paper_lft_design():
    """Theorem 1's design on the paper's box γ ∈ [0.5, 1]⁴ (an LMI solve: made once per process)."""
    return lft_uio_design(PAPER, LOW, HIGH)


TRUE_GAINS = np.array([0.6, 0.75, 1.0, 1.0])


def linear_window(gamma, steps=50, seed=0, bias=2.0):
    """Readings and inputs of the paper's plant (58) over a window: y = Δ(γ) C x + F b."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=3)
    ys, us = [], []
    for k in range(steps):
        u = 8.0 * np.sign(np.sin(2 * np.pi * np.array([k / 30, k / 19 + 0.16])))
        ys.append(gamma * (C @ x) + bias)
        us.append(u)
        x = A @ x + B @ u + E[:, 0] * 0.05 * np.sin(2 * np.pi * k / 23 + rng.random())
    return np.array(ys), np.array(us)


def simulate(est, steps, gamma_of_t, bias_of_t, seed=0, oracle=False):
    """The paper's linear plant (58) driven by square-wave inflows and a sinusoidal unknown input."""
    x = np.zeros(3)
    rows = []
    for k in range(steps):
        u = 30.0 * np.sign(np.sin(2 * np.pi * np.array([k / 150, k / 97 + 0.16])))
        v = 0.05 * np.sin(2 * np.pi * k / 90)
        gamma = gamma_of_t(k)
        y = gamma * (C @ x) + bias_of_t(k)
        if oracle and k >= est.params.window:
            est.gamma = gamma.copy()
        estimate = est.step(y, u)
        rows.append(
            (
                np.linalg.norm(estimate.x - x),
                estimate.diagnostics["zhat"] - np.dot(HZ, C @ x),
                np.dot(HZ, y) - np.dot(HZ, C @ x),
                estimate.diagnostics,
            )
        )
        x = A @ x + B @ u + E[:, 0] * v
    return rows


WINDOW = 50  # N, the parameter estimator's horizon (Sec. 4)
