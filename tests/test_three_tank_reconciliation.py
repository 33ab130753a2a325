"""The built-in scenario three-tank-reconciliation through the co-simulation (MJCF plant → faults →
CAN → seven estimator processes → MCAP), asserted on its log. Designs included (the LPV design of
Theorem 1 is about 10 s on a fresh cache), the run takes 30-50 s on two cores."""

from __future__ import annotations

import numpy as np
import pytest

from cosim import scenario
from cosim.analysis.series import load
from cosim.log.reader import LogReader
from cosim.run import run
from tests.doc_figures import check, three_tank_figures, undocumented

pytestmark = pytest.mark.slow  # seven node processes over 1500 ticks

HZ = np.array([1 / 3, 1 / 3, 0.0, 1 / 3])


PAPER, OURS, TESTED = ("lpv", "lft"), ("lpv_model", "lft_model"), ("lpv_test", "lft_test")
TRUE = {"bias only": (1.0, 1.0, 1.0, 1.0), "gamma1": (0.6, 1.0, 1.0, 1.0), "both": (0.6, 0.75, 1.0, 1.0)}


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    result = run(scenario.load("three-tank-reconciliation"), tmp_path_factory.mktemp("tt") / "tt.mcap")
    assert result.status == "completed" and result.frames_lost == 0
    with LogReader(result.path) as reader:
        z_true = {
            msg["tick"]: float(HZ @ np.array([msg[f"y{i}"] for i in (1, 2, 3, 4)]))
            for _, _, msg in reader.messages(["/truth/sensors"])
        }
    estimates = load(result.path).estimators
    z_hat = {
        name: {k: v["zhat"] for k, v in estimates[name].values.items()} for name in (*PAPER, *OURS, *TESTED, "raw")
    }
    gamma = {
        name: {k: np.array([v[f"gamma_y{i}"] for i in (1, 2, 3, 4)]) for k, v in estimates[name].values.items()}
        for name in (*PAPER, *OURS, *TESTED)
    }
    return z_true, z_hat, gamma, result.path


def rms(z_true, z_hat, ticks):
    return float(np.sqrt(np.mean([(z_hat[k] - z_true[k]) ** 2 for k in ticks])))


def test_the_bias_is_rejected_where_hz_y_is_falsified(series):
    """Bias on, gains healthy (300-400 s). Measured: raw 2.00; LFT 0.014, LPV 0.032 (the paper's
    schemes), 0.027 for both with the model-window gain estimator, whose γ̂ wanders by < 0.01 on
    the nonlinear plant."""
    z_true, z_hat, _, _ = series
    window = range(300, 400)
    raw = rms(z_true, z_hat["raw"], window)
    assert raw == pytest.approx(2.0, rel=0.01)  # H_z F b = b
    for name in (*PAPER, *OURS, *TESTED):
        assert rms(z_true, z_hat[name], window) < 0.025 * raw, name


def test_with_the_model_window_the_gains_converge_after_the_window_fills(series):
    """γ̂ once the N = 50 window holds only samples after a fault onset: γ1 = 0.6 from 400 s, then
    γ2 = 0.75 from 700 s. Tolerance reached on the MJCF plant (model mismatch of the linearization;
    exact on the linear model, tests/test_model_window.py): |γ̂ − γ| at most 0.030, RMS per
    sensor at most 0.007. Windows across an onset do not fit (``fit`` > fit_tol) and keep γ̂."""
    _, _, gamma, _ = series
    for name in OURS:
        for ticks, true in ((range(450, 700), TRUE["gamma1"]), (range(750, 1500), TRUE["both"])):
            error = np.array([gamma[name][k] - true for k in ticks])
            assert np.abs(error).max() < 0.035, (name, ticks)
            assert np.sqrt(np.mean(error**2, axis=0)).max() < 0.01, (name, ticks)


def test_with_the_model_window_the_reconciled_output_tracks_z(series):
    """After the gain faults (450-700 s, 750-1500 s) ẑ tracks z: RMS 0.030-0.049 against H_z y's
    1.52 and 1.72 (at most 2.9 % of it), the paper's Figure 9."""
    z_true, z_hat, _, _ = series
    for ticks in (range(450, 700), range(750, 1500)):
        raw = rms(z_true, z_hat["raw"], ticks)
        assert 1.4 < raw < 1.9
        for name in OURS:
            assert rms(z_true, z_hat[name], ticks) < 0.05 * raw, name


def test_the_papers_gain_estimator_does_not_converge(series):
    """Finding, measured (docs/three-tank.md): with (53) regressing y on the UIO's own x̂, γ̂₁ is
    still 0.85 (LFT) and 0.93 (LPV) at 1500 s for a true 0.6, and ẑ after the gain faults is no
    better than H_z y (RMS 1.71 and 1.97 against 1.72)."""
    z_true, z_hat, gamma, _ = series
    for name in PAPER:
        assert gamma[name][1499][0] > 0.8, gamma[name][1499]
        assert rms(z_true, z_hat[name], range(750, 1500)) > 0.8 * rms(z_true, z_hat["raw"], range(750, 1500))


def test_cosim_plot_draws_the_gain_estimates_against_the_true_gains_and_z_hat_against_z(series, tmp_path):
    from cosim.analysis.plot import plot
    from cosim.analysis.series import load as load_series
    from cosim.analysis.series import true_gains, virtual_output

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


def test_with_the_gain_test_gamma_moves_only_at_the_faults(series):
    """Issue 18 on the MJCF plant: before the first gain fault (and across the bias step at 200 s)
    no window rejects γ = 1, so γ̂ is exactly 1; the faulty gains within 0.02 of the truth (the
    README's row, with margin: measured 0.0004) from one window after each onset; the sensors that
    stay healthy at 1 throughout (within 0.02: measured exactly 1)."""
    _, _, gamma, _ = series
    for name in TESTED:
        g = np.array([gamma[name][k] for k in range(1500)])
        assert np.all(g[:400] == 1.0), name
        assert np.abs(g[:, 2:] - 1.0).max() <= 0.02 and np.abs(g[:700, 1] - 1.0).max() <= 0.02, name
        assert np.abs(g[450:, 0] - 0.6).max() <= 0.02, name
        assert np.abs(g[750:, 1] - 0.75).max() <= 0.02, name


def test_with_the_gain_test_the_reconciled_output_is_100_times_better_than_hz_y(series):
    """After the gain faults ẑ's RMS error is 0.0040 (450-700 s) and 0.0025-0.0027 (750-1500 s),
    against H_z y's 1.52 and 1.72: at least 100× below it (measured 370-690×)."""
    z_true, z_hat, _, _ = series
    for ticks in (range(450, 700), range(750, 1500)):
        for name in TESTED:
            assert 100 * rms(z_true, z_hat[name], ticks) < rms(z_true, z_hat["raw"], ticks), (name, ticks)


def test_the_documented_figures_are_what_the_run_gives(series):
    """docs/three-tank.md's results (``python -m tests.doc_figures three-tank-reconciliation``) within
    half a unit of their last printed digit plus 2 %, and each printed in the document."""
    *_, path = series
    assert check("three-tank-reconciliation", three_tank_figures(path)) == []
    assert undocumented("three-tank-reconciliation") == []
