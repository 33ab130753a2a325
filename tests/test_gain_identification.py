"""The gain test (ours: γ̂ changes only on evidence; docs/three-tank.md, "The gain test") of
estimators/gain_identification.py, on the paper's linear plant (58) with noise: γ and ẑ kept
without a fault, a single gain fault identified on any sensor, the paper's gain profile, a window
without excitation."""

from __future__ import annotations

import numpy as np
import pytest

import estimators
from tests.paper_three_tank import HZ, TRUE_GAINS, WINDOW, A, B, C, E, linear_window, paper_lft_design, paper_model


@pytest.fixture(scope="module")
def lft_design():
    return paper_lft_design()


# Issue 18's requirements, on the paper's linear plant (58) with the scenario's excitation (square
# waves of ±8 cm³/s, periods 150 s and 97 s; v = 0.02 sin(2πt/90 s)) and 0.01 cm of white noise
# on every sensor, added before the gain as the testbed does (noise first, then the faults).

NOISE = 0.01


def gain_test(lft_design, kind="lft-uio-sr", **params):
    """Algorithm 2 (or 1, with the LFT gain at every vertex: any gain the LMIs certify would do) with
    ``gain_estimator = "test"`` told the noise level."""
    base = {"Hz": HZ, "design_gamma_min": 0.5, "gain_estimator": "test", "noise_std": NOISE}
    if kind == "lft-uio-sr":
        base["L"] = lft_design.L.tolist()
    else:
        base |= {"G": np.tile(np.eye(4), (16, 1)).tolist(), "Y": np.tile(lft_design.L, (16, 1)).tolist()}
    return estimators.create(kind, paper_model(), base | params)


def simulate_noisy(est, steps, gamma_of_t, bias_of_t, seed, inputs=None, x0=None, v=0.02):
    """The linear plant (58), y = Δ(γ)(C x + n) + F b with n ~ N(0, 0.01²), unknown input
    v sin(2πt/90 s); returns per tick γ̂ (4), ẑ − z, H_z y − z and the ``pe`` diagnostic."""
    rng = np.random.default_rng(seed)
    x = np.zeros(3) if x0 is None else x0
    gammas, z_err, raw, pe = [], [], [], []
    for k in range(steps):
        u = 8.0 * np.sign(np.sin(2 * np.pi * np.array([k / 150, k / 97 + 0.16]))) if inputs is None else inputs(k)
        y = gamma_of_t(k) * (C @ x + NOISE * rng.standard_normal(4)) + bias_of_t(k)
        d = est.step(y, u).diagnostics
        z = np.dot(HZ, C @ x)
        gammas.append([d[f"gamma_y{i}"] for i in (1, 2, 3, 4)])
        z_err.append(d["zhat"] - z)
        raw.append(np.dot(HZ, y) - z)
        pe.append(d["pe"])
        x = A @ x + B @ u + E[:, 0] * v * np.sin(2 * np.pi * k / 90)
    return np.array(gammas), np.array(z_err), np.array(raw), np.array(pe)


def rms(values):
    return float(np.sqrt(np.mean(np.square(values))))


def single_gain(sensor, onset, gain=0.6):
    return lambda k: np.where((np.arange(4) == sensor) & (k >= onset), gain, 1.0)


def test_without_a_fault_the_gain_test_keeps_gamma_and_z_hat_as_good_as_53(lft_design):
    """No fault for 1500 s with 0.01 cm noise: every γ̂ within 0.01 of 1 once the window has filled
    (measured: exactly 1, no window rejects it at α = 1e-6), and ẑ's RMS error within 1.5× that of
    the paper's (53) on the same readings (measured: 0.0098 against 0.0097, 1.01×; (53)'s own γ̂
    wanders by 0.011). The model-window estimator on the same readings wanders by 0.056 (the issue's
    complaint), which the first assertion would catch."""
    healthy, no_bias = (lambda k: np.ones(4)), (lambda k: 0.0)
    gammas, z_test, _, _ = simulate_noisy(gain_test(lft_design), 1500, healthy, no_bias, seed=18)
    paper = estimators.create(
        "lft-uio-sr", paper_model(), {"Hz": HZ, "design_gamma_min": 0.5, "L": lft_design.L.tolist()}
    )
    _, z_paper, _, _ = simulate_noisy(paper, 1500, healthy, no_bias, seed=18)
    assert np.abs(gammas[WINDOW:] - 1.0).max() <= 0.01
    assert rms(z_test[WINDOW:]) <= 1.5 * rms(z_paper[WINDOW:])
    model = estimators.create(
        "lft-uio-sr",
        paper_model(),
        {"Hz": HZ, "design_gamma_min": 0.5, "L": lft_design.L.tolist(), "gain_estimator": "model", "fit_tol": 0.12},
    )
    wandering, _, _, _ = simulate_noisy(model, 600, healthy, no_bias, seed=18)
    assert np.abs(wandering[WINDOW:] - 1.0).max() > 0.01


def check_single_gain_fault(est, sensor, onset, steps, seed, bias=2.0, since=0):
    """Issue 18: the faulty γ̂ within 0.03 of 0.6 from 2 windows after the onset on; every healthy
    γ̂ within 0.02 of 1 at all times; ẑ's RMS error from the onset on at least 10× below H_z y's
    when the faulty sensor is in H_z (sensor 3 is not: H_z y does not see its fault)."""
    gammas, z_err, raw, _ = simulate_noisy(est, steps, single_gain(sensor, onset), lambda k: bias * (k >= 150), seed)
    assert np.abs(gammas[onset + 2 * WINDOW :, sensor] - 0.6).max() <= 0.03
    assert np.abs(np.delete(gammas, sensor, axis=1) - 1.0).max() <= 0.02
    if HZ[sensor] != 0.0:
        assert rms(z_err[onset + since :]) * 10 <= rms(raw[onset + since :])
    return gammas, z_err, raw


@pytest.mark.slow
@pytest.mark.parametrize("sensor, onset", [(0, 250), (1, 430), (2, 610), (3, 790)])
def test_a_single_gain_fault_on_any_sensor_is_identified_by_the_gain_test(lft_design, sensor, onset):
    """Each sensor in turn to 0.6, onsets across 200-800 s, the 2 cm bias from 150 s, 300 s after
    the onset. Measured (linear model, 0.01 cm noise): the faulty γ̂ within 0.03 of 0.6 after
    9-11 samples and within 0.016 two windows after the onset (0.004 but for y3); healthy γ̂
    exactly 1; RMS ratios H_z y / ẑ of 18-23 from the onset."""
    check_single_gain_fault(gain_test(lft_design), sensor, onset, onset + 300, seed=sensor)


@pytest.mark.parametrize("sensor, onset", [(0, 640), (3, 330)])
def test_a_single_gain_fault_without_bias_is_identified_by_the_gain_test(lft_design, sensor, onset):
    """The same without the bias: γ̂ as with it (identified after 9 samples, within 0.003 of 0.6
    two windows after the onset, the healthy ones exactly 1). H_z y is then wrong by the gain fault
    alone, by 0.26 RMS for y4 (H_z weighs it 1/3, its levels move a few cm), and over the first
    20 s, while the UIO coasts on its prediction until the change is identified, ẑ is off by 0.33
    RMS: worse than H_z y there (the unknown input v is not in the prediction). So ẑ is compared
    with H_z y from two windows after the onset: measured 23× (y4) and 153× (y1) better."""
    check_single_gain_fault(
        gain_test(lft_design), sensor, onset, onset + 300, seed=40 + sensor, bias=0.0, since=2 * WINDOW
    )


@pytest.mark.slow
@pytest.mark.parametrize("sensor", range(4))
@pytest.mark.parametrize("onset", [200, 517, 800])
def test_a_single_gain_fault_over_1500_s(lft_design, sensor, onset):
    """The same over the scenario's 1500 s, onset at both ends of 200-800 s and between. Measured:
    the faulty γ̂ within 0.006 of 0.6 two windows after the onset, RMS ratios H_z y / ẑ of 28-68
    from the onset."""
    check_single_gain_fault(gain_test(lft_design), sensor, onset, 1500, seed=10 * sensor + onset)


@pytest.mark.parametrize("kind", ["lft-uio-sr", pytest.param("lpv-uio-sr", marks=pytest.mark.slow)])
def test_the_gain_test_identifies_the_papers_gain_profile(lft_design, kind):
    """Fig. 7's profile (γ1 = 0.6 from 400 s, γ2 = 0.75 from 700 s, bias from 200 s) with 0.01 cm
    noise: γ̂ within 0.01 of γ two windows after each onset (measured 0.001), the sensors that stay
    healthy at 1, ẑ's RMS error after 800 s below 1 % of H_z y's."""
    true = np.array([0.6, 0.75, 1.0, 1.0])

    def gamma_of_t(k):
        return np.where(np.array([k >= 400, k >= 700, False, False]), true, 1.0)

    gammas, z_err, raw, pe = simulate_noisy(
        gain_test(lft_design, kind), 1000, gamma_of_t, lambda k: 2.0 * (k >= 200), 7
    )
    np.testing.assert_allclose(gammas[500:700, 0], 0.6, atol=0.01)
    np.testing.assert_allclose(gammas[800:], np.tile(true, (200, 1)), atol=0.01)
    assert np.all(gammas[:, 2:] == 1.0) and np.all(gammas[:700, 1] == 1.0)
    assert rms(z_err[800:]) < 0.01 * rms(raw[800:])
    assert np.all(pe[800:] > 0)  # the square waves excite every window


@pytest.mark.slow
def test_a_window_without_excitation_is_reported_and_gamma_kept(lft_design):
    """Constant inputs from the steady state they hold, no unknown input: the levels do not move, so a gain change
    on sensor 1 at 300 s is indistinguishable from a step of its offset (y1 = γ C1 x + d1 with C1 x
    constant). The windows say so (``pe`` = 0) and γ̂ is not guessed: it stays 1. Once the inputs
    move (500 s) the same data identify γ1 = 0.6."""
    steady = np.array([8.0, -8.0])
    x0 = np.linalg.solve(np.eye(3) - A, B @ steady)

    def inputs(k):
        return steady if k < 500 else 8.0 * np.sign(np.sin(2 * np.pi * np.array([k / 150, k / 97 + 0.16])))

    gammas, _, _, pe = simulate_noisy(
        gain_test(lft_design), 800, single_gain(0, 300), lambda k: 2.0 * (k >= 100), 1, inputs, x0, v=0.0
    )
    assert np.all(pe[350:500] == 0.0) and np.all(gammas[:500] == 1.0)
    # Measured: γ̂1 = 0.6004 from 540 s; pe > 0 in 98 % of the windows after 550 s (the few others
    # hold too few switchings of the square waves: reported as such, γ̂ kept).
    assert np.abs(gammas[500 + 2 * WINDOW :, 0] - 0.6).max() <= 0.03 and np.mean(pe[600:] > 0) > 0.9
    assert np.all(gammas[:, 1:] == 1.0)


def test_the_gain_tests_window_system_is_its_statistics_definition():
    """The tick's window system (the whole window, every reading there) reduced by the complement
    of the nuisance columns gives, for any β, T(β) = ‖P⊥ D (Y β − r)‖² with P⊥ = I − Q Qᵀ, Q a basis
    of range(Z), its degrees of freedom N m − rank Z, and the standard errors 1/‖P⊥ D Y_j‖."""
    from estimators.gain_identification import chi2_statistic, gain_standard_errors, gain_test_window, window_system

    sigma = np.array([0.01, 0.02, 0.01, 0.03])
    window = gain_test_window(A, np.hstack([B, np.ones((3, 1))]), E, C, sigma, WINDOW, 10)
    ys, us = linear_window(TRUE_GAINS, WINDOW, seed=3)
    us = np.hstack([us, np.ones((WINDOW, 1))])
    system = window_system(window, ys, us)
    Q = window.bases[-1]
    projector = np.eye(len(Q)) - Q @ Q.T
    Y = np.zeros((WINDOW * 4, 4))
    Y[np.arange(WINDOW * 4), np.tile(np.arange(4), WINDOW)] = (ys / sigma).ravel()
    r = np.einsum("kjil,il->kj", window.forced, us[:-1]).ravel()
    assert system.dof == WINDOW * 4 - Q.shape[1]
    rng = np.random.default_rng(4)
    for beta in [1.0 / TRUE_GAINS, np.ones(4), *rng.uniform(1.0, 2.0, (5, 4))]:
        direct = np.sum((projector @ (Y @ beta - r)) ** 2)
        assert chi2_statistic(system, beta) == pytest.approx(direct, rel=1e-9, abs=1e-9 * (r @ r))
    np.testing.assert_allclose(gain_standard_errors(system), 1 / np.linalg.norm(projector @ Y, axis=0), rtol=1e-9)
