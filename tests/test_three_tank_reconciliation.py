"""The built-in scenario three-tank-reconciliation through the co-simulation (MJCF plant → faults →
CAN → three estimator processes → MCAP), asserted on its log. Designs included (the LPV design of
Theorem 1 is about 10 s on a fresh cache), the run takes about 30 s."""

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
    return z_true, z_hat, gamma, result.path


def rms(z_true, z_hat, ticks):
    return float(np.sqrt(np.mean([(z_hat[k] - z_true[k]) ** 2 for k in ticks])))


def test_the_bias_is_reduced_where_hz_y_is_falsified(series):
    """Bias on, gains healthy (300-400 s). Measured on the MJCF plant: raw 2.00, LFT 0.06, LPV 0.50
    (the nonlinear plant departs from the linear design model; on the linear model (58) both reach
    0.09, tests/test_reconciliation.py)."""
    z_true, z_hat, _, _ = series
    window = range(300, 400)
    raw = rms(z_true, z_hat["raw"], window)
    assert raw == pytest.approx(2.0, rel=0.01)  # H_z F b = b
    assert rms(z_true, z_hat["lft"], window) < 0.1 * raw
    assert rms(z_true, z_hat["lpv"], window) < 0.5 * raw


def test_after_the_gain_faults_the_reconciled_output_beats_the_uncorrected_one(series):
    """Gains 0.6 and 0.75 on sensors 1 and 2 and the bias (750-1500 s). Measured: raw 1.95, LFT 1.08,
    LPV 1.35: better than H_z y, but far from the paper's Figure 9 (ẑ on z)."""
    z_true, z_hat, _, _ = series
    window = range(750, 1500)
    raw = rms(z_true, z_hat["raw"], window)
    assert 1.8 < raw < 2.1
    assert rms(z_true, z_hat["lft"], window) < 0.65 * raw
    assert rms(z_true, z_hat["lpv"], window) < 0.8 * raw


def test_gain_estimates_move_toward_the_faulty_gains(series):
    """Measured, not the paper's claim: after 1500 s γ̂₁ is 0.85 (LPV) and 0.77 (LFT) against the true
    0.6 (docs/three-tank.md: the UIO's decoupling term Q y absorbs most of a gain fault, so (53)
    converges slowly)."""
    _, _, gamma, _ = series
    assert gamma["lft"][1499][0] < 0.8, gamma["lft"][1499]
    assert gamma["lpv"][1499][0] < 0.9, gamma["lpv"][1499]


def test_cosim_plot_draws_the_gain_estimates_against_the_true_gains_and_z_hat_against_z(series, tmp_path):
    from cosim.plot import load as load_series
    from cosim.plot import plot, true_gains, virtual_output

    *_, path = series
    written = {p.name for p in plot(path, tmp_path)}
    assert {"gain_estimate.png", "virtual_output.png", "error.png"} <= written
    assert "weights.png" not in written  # γ̂ is not a pseudoinverse weight
    loaded = load_series(path)
    gains = true_gains(loaded, np.array([0.0, 399.0, 400.0, 699.0, 700.0, 1499.0]))
    assert gains[:, 0].tolist() == [1.0, 1.0, 0.6, 0.6, 0.6, 0.6]
    assert gains[:, 1].tolist() == [1.0, 1.0, 1.0, 1.0, 0.75, 0.75]
    assert (gains[:, 2:] == 1.0).all()
    t, zhat, z = virtual_output(loaded, "raw")
    assert len(t) == 1500 and np.allclose(zhat[:200], z[:200], atol=1e-9)  # healthy sensors: H_z y = z
