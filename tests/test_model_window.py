"""The gain estimator on the model (ours; docs/three-tank.md): the model window of the paper's plant
(58) eliminates the nuisance unknowns, and its gains are exact, kept in the box and kept across a
fault onset, where the paper's regression (53) cannot tell the gains apart."""

from __future__ import annotations

import numpy as np
import pytest

import estimators
from estimators.model_window import model_window, window_gains
from estimators.sample_window import Sample
from tests.paper_three_tank import HZ, TRUE_GAINS, A, B, C, E, linear_window, paper_lft_design, paper_model, simulate


@pytest.fixture(scope="module")
def lft_design():
    return paper_lft_design()


def test_the_model_window_eliminates_the_nuisance_unknowns():
    window = model_window(A, B, E, C, 50)
    by_sensor = window.projection.by_sensor
    W = by_sensor.transpose(1, 2, 0).reshape(by_sensor.shape[1], -1)  # (R, N m), sample-major
    np.testing.assert_allclose(W @ W.T, np.eye(len(W)), atol=1e-10)  # orthonormal
    assert np.abs(W @ window.nuisance).max() < 1e-9 * np.abs(window.nuisance).max()  # ⟂ range(Z)
    # 4·50 equations; d (4), x_p(0) (3), v (49) less the one direction they share (a steady state
    # under constant v, offset by d) leave 200 − 55 for β.
    assert len(W) == 200 - 55


def test_window_gains_recover_any_gains_in_the_box_exactly():
    window = model_window(A, B, E, C, 50)
    rng = np.random.default_rng(6)
    for seed in range(10):
        gamma = 0.5 + 0.5 * rng.random(4)
        ys, us = linear_window(gamma, seed=seed, bias=rng.normal() * 3)
        estimate, sv, fit = window_gains(window, ys, us, np.full(4, 0.5), np.ones(4))
        np.testing.assert_allclose(estimate, gamma, rtol=1e-8)
        assert sv[-1] / sv[0] > 1e-3 and fit < 1e-9
        ys[[3, 17, 40], [0, 2, 3]] = np.nan  # readings that did not arrive: their equations drop out
        np.testing.assert_allclose(window_gains(window, ys, us, np.full(4, 0.5), np.ones(4))[0], gamma, rtol=1e-8)


def test_window_gains_stay_in_the_box():
    window = model_window(A, B, E, C, 50)
    ys, us = linear_window(np.array([0.3, 0.75, 1.0, 1.0]))
    estimate, _, fit = window_gains(window, ys, us, np.full(4, 0.5), np.ones(4))
    assert estimate[0] == pytest.approx(0.5) and np.all((estimate >= 0.5 - 1e-12) & (estimate <= 1 + 1e-12))
    assert fit > 0.1  # γ1 = 0.3 is outside the box: no γ in it explains the window


def test_a_window_across_a_fault_onset_does_not_fit_and_keeps_the_estimate():
    """Half the window with γ1 = 1, half with 0.6: no single γ explains it. The relative residual
    is far above fit_tol and the estimator keeps γ̂; once the window is past the onset it fits."""
    window = model_window(A, B, E, C, 50)
    before, us = linear_window(np.ones(4), steps=50)
    after, _ = linear_window(TRUE_GAINS, steps=50)
    mixed = np.vstack([before[:25], after[25:]])
    assert window_gains(window, mixed, us, np.full(4, 0.5), np.ones(4))[2] > 0.1
    est = estimators.create("lft-uio-sr", paper_model(), {"Hz": HZ, "design_gamma_min": 0.5, "gain_estimator": "model"})
    est.gamma = np.array([0.9, 1.0, 1.0, 1.0])
    est.history.extend(Sample(y, np.zeros(3), np.zeros(1), y, np.append(u, 1.0)) for y, u in zip(mixed, us))
    assert np.array_equal(est._estimate_gamma_on_the_model(), [0.9, 1.0, 1.0, 1.0]) and est.fit > 0.1
    est.history.clear()
    est.history.extend(Sample(y, np.zeros(3), np.zeros(1), y, np.append(u, 1.0)) for y, u in zip(after, us))
    np.testing.assert_allclose(est._estimate_gamma_on_the_model(), TRUE_GAINS, rtol=1e-8)


def test_the_papers_regression_cannot_tell_the_gains_apart(lft_design):
    """Finding (docs/three-tank.md): hold γ̂ = (0.8, 0.9, 1, 1) against the true (0.6, 0.75, 1, 1).
    The UIO's x̂ then explains y through γ̂ almost as well as the truth does, so (53) returns
    nearly γ̂ again: the alternation UIO ↔ (53) hardly moves. The model window returns γ."""
    est = estimators.create(
        "lft-uio-sr", paper_model(), {"Hz": HZ, "design_gamma_min": 0.5, "L": lft_design.L.tolist(), "window": 300}
    )
    held = np.array([0.8, 0.9, 1.0, 1.0])
    x = np.zeros(3)
    for k in range(600):
        u = 8.0 * np.sign(np.sin(2 * np.pi * np.array([k / 150, k / 97 + 0.16])))
        est.gamma = held
        est.step(TRUE_GAINS * (C @ x) + 2.0, u)
        x = A @ x + B @ u + E[:, 0] * 0.02 * np.sin(2 * np.pi * k / 90)
    regressed = est._estimate_gamma()
    assert np.abs(held - TRUE_GAINS)[:2].min() >= 0.15  # far from the truth ...
    assert np.abs(regressed - held).max() < 0.02  # ... and (53) hands γ̂ back
    window = model_window(A, est.aug.B, E, C, 300)
    ys, us = np.array([s.measured for s in est.history]), np.array([s.u for s in est.history])
    np.testing.assert_allclose(window_gains(window, ys, us, est.lower, est.upper)[0], TRUE_GAINS, rtol=1e-8)


@pytest.mark.parametrize("kind", ["lft-uio-sr", "lpv-uio-sr"])
def test_with_the_model_window_the_gains_and_the_virtual_output_converge(kind, lft_design):
    """Algorithms 1 and 2 with the model-window gain estimator on the linear plant (58): γ̂ = γ to
    1e-6 once the window has passed each fault, and then ẑ = z (Remark 3)."""
    params = {"Hz": HZ, "design_gamma_min": 0.5, "gain_estimator": "model"}
    if kind == "lft-uio-sr":
        params["L"] = lft_design.L.tolist()
    else:  # a cheap scheduled gain: the LFT gain at every vertex (any gain the LMIs certify would do)
        params |= {"G": np.tile(np.eye(4), (16, 1)).tolist(), "Y": np.tile(lft_design.L, (16, 1)).tolist()}
    est = estimators.create(kind, paper_model(), params)

    def gamma_of_t(k):
        return np.where(np.array([k >= 100, k >= 300, False, False]), [0.6, 0.75, 1, 1], 1.0)

    rows = simulate(est, 700, gamma_of_t, lambda k: 2.0 * (k >= 50))
    gammas = np.array([[r[3][f"gamma_y{i}"] for i in (1, 2, 3, 4)] for r in rows])
    np.testing.assert_allclose(gammas[160:300, 0], 0.6, atol=1e-6)
    np.testing.assert_allclose(gammas[360:], np.tile(TRUE_GAINS, (340, 1)), atol=1e-6)
    assert max(abs(r[1]) for r in rows[500:]) < 1e-6
    assert rows[-1][3]["pe"] > 0
