"""The built-in scenario three-tank-reconciliation through the co-simulation (MJCF plant → faults →
CAN → three estimator processes → MCAP), asserted on its log. Designs included (the LPV design of
Theorem 1 is about 100 s on a fresh cache), the run takes about 2 minutes."""

from __future__ import annotations

import numpy as np
import pytest

from cosim import scenario
from cosim.log import LogReader
from cosim.plot import load
from cosim.runner import run

HZ = np.array([1 / 3, 1 / 3, 0.0, 1 / 3])


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    result = run(scenario.load("three-tank-reconciliation"), tmp_path_factory.mktemp("tt") / "tt.mcap")
    assert result.status == "completed" and result.frames_lost == 0
    with LogReader(result.path) as reader:
        z_true = {msg["tick"]: float(HZ @ np.array([msg[f"y{i}"] for i in (1, 2, 3, 4)])) for _, _, msg in reader.messages(["/truth/sensors"])}
    estimates = load(result.path).estimators
    z_hat = {name: {k: v["zhat"] for k, v in estimates[name].values.items()} for name in ("lpv", "lft", "raw")}
    gamma = {name: {k: [v[f"gamma_y{i}"] for i in (1, 2, 3, 4)] for k, v in estimates[name].values.items()} for name in ("lpv", "lft")}
    return z_true, z_hat, gamma


def rms(z_true, z_hat, ticks):
    return float(np.sqrt(np.mean([(z_hat[k] - z_true[k]) ** 2 for k in ticks])))


def test_the_bias_is_reduced_where_hz_y_is_falsified(series):
    """Bias on, gains healthy (300-400 s). Measured on the MJCF plant: raw 2.00, LFT 0.11, LPV 0.80
    (the nonlinear plant departs from the linear design model; on the linear model (58) both reach
    0.09, tests/test_reconciliation.py)."""
    z_true, z_hat, _ = series
    window = range(300, 400)
    raw = rms(z_true, z_hat["raw"], window)
    assert raw == pytest.approx(2.0, rel=0.01)  # H_z F b = b
    assert rms(z_true, z_hat["lft"], window) < 0.1 * raw
    assert rms(z_true, z_hat["lpv"], window) < 0.5 * raw


def test_gain_estimates_move_toward_the_faulty_gains(series):
    """Measured, not the paper's claim: after 1500 s γ̂₁ is 0.77 (LPV) and 0.72 (LFT) against the true
    0.6, and γ̂₂ 0.93 and 0.50 against 0.75 (docs/three-tank.md: the UIO's decoupling term Q y
    absorbs most of a gain fault, so (53) converges slowly)."""
    _, _, gamma = series
    for name in ("lpv", "lft"):
        assert gamma[name][1499][0] < 0.85, (name, gamma[name][1499])
