"""Estimators against the paper (TAC 2024) and against textbook Kalman filter properties."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

import estimators
from estimators import ParameterError
from estimators.design import is_schur, observer_gain, output_factorization, weighted_pseudoinverse
from estimators.kalman import KalmanFilter
from estimators.pseudoinverse import PseudoinverseObserver
from mjcf import masses
from tests.linear_masses import masses_model

SENSORS = ("x1", "x2", "x1_minus_x2")
POLES = (0.75, 0.8, 0.85, 0.9)


def test_factorization_reproduces_example_1():
    """Y and H of eq. (4a)–(4b) for C of eq. (3), with YᵀY = I and C = Y H."""
    C = masses.output_matrix(SENSORS)
    Y, H = output_factorization(C)
    r3 = math.sqrt(3)
    Y_paper = np.array([[(3 + r3) / 6, (3 - r3) / 6, 1 / r3], [(3 - r3) / 6, (3 + r3) / 6, -1 / r3]]).T
    H_paper = np.array(
        [[(3 + r3) / (2 * r3), (-3 + r3) / (2 * r3), 0, 0], [(-3 + r3) / (2 * r3), (3 + r3) / (2 * r3), 0, 0]]
    )
    np.testing.assert_allclose(Y, Y_paper, atol=1e-15)
    np.testing.assert_allclose(H, H_paper, atol=1e-15)
    np.testing.assert_allclose(Y.T @ Y, np.eye(2), atol=1e-15)
    np.testing.assert_allclose(Y @ H, C, atol=1e-15)


def test_observer_gain_places_the_papers_spectrum():
    model = masses_model()
    _, H = output_factorization(model.C)
    L = observer_gain(model.A, H, POLES)
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(model.A - L @ H).real), POLES, atol=1e-9)
    assert np.allclose(np.linalg.eigvals(model.A - L @ H).imag, 0, atol=1e-9)


def test_weighted_pseudoinverse_properties():
    """Π(s) Y = I (used in eq. (19)), Π(μ s) = Π(s), and Γ(s)φ = Γ(φ)s (eq. (18))."""
    Y, _ = output_factorization(masses.output_matrix(SENSORS))
    rng = np.random.default_rng(0)
    for _ in range(10):
        s, phi = rng.uniform(0.1, 1.0, 3), rng.normal(size=3)
        Pi = weighted_pseudoinverse(Y, s)
        np.testing.assert_allclose(Pi @ Y, np.eye(2), atol=1e-12)
        np.testing.assert_allclose(weighted_pseudoinverse(Y, -3.7 * s), Pi, atol=1e-12)
        np.testing.assert_allclose((Y.T * s) @ phi, (Y.T * phi) @ s, atol=1e-14)


def simulate(estimator, model, steps, phi=None, x0=(0.2, -0.1, 0.0, 0.3), drop=None):
    """Noise-free simulation of the exact discrete plant; returns the errors x_k − x̂_k."""
    x = np.array(x0, dtype=float)
    errors = []
    for k in range(steps):
        u = np.array([math.sin(2 * math.pi * 0.5 * k * 0.01)])
        y = model.C @ x + (0 if phi is None else phi)
        if drop is not None:
            y = y.copy()
            y[drop] = np.nan
        errors.append(x - estimator.step(y, u).x)
        x = model.A @ x + model.B @ u
    return np.array(errors)


def test_uniform_pseudoinverse_observer_converges_without_bias():
    model = masses_model()
    obs = estimators.create("pseudoinverse", model, {"poles": POLES})
    np.testing.assert_allclose(obs.weights, np.full(3, 1 / math.sqrt(3)))
    errors = np.linalg.norm(simulate(obs, model, 600), axis=1)
    # e_k = (A − L H)^k e_0: the spectral radius 0.9 bounds the decay rate
    assert errors[-1] < 1e-12
    assert errors[300] < 1e3 * 0.9**300 * errors[0]


def test_uniform_observer_has_the_steady_error_of_eq_19_under_a_constant_bias():
    """e⁺ = (A − L H) e − L Π(s) φ, so e → −(I − A + L H)⁻¹ L Π(s) φ ≠ 0 (Sec. VII-A baseline)."""
    model = masses_model()
    phi = np.array([1.0, -1.5, 0.5])
    obs = PseudoinverseObserver.from_params(model, {"poles": POLES})
    errors = simulate(obs, model, 2000, phi=phi)
    expected = -np.linalg.solve(np.eye(4) - model.A + obs.L @ obs.H, obs.L @ obs.Pi @ phi)
    np.testing.assert_allclose(errors[-1], expected, atol=1e-10)
    assert np.linalg.norm(expected) > 0.5


def test_a_missing_reading_gets_weight_zero():
    model = masses_model()
    obs = estimators.create("pseudoinverse", model, {"poles": POLES})
    errors = simulate(obs, model, 800, drop=[2])  # the range sensor never arrives
    assert np.linalg.norm(errors[-1]) < 1e-9


def test_no_readings_means_open_loop_prediction():
    model = masses_model()
    obs = estimators.create("pseudoinverse", model, {"poles": POLES, "x0": (0.1, 0.0, 0.0, 0.0)})
    u = np.array([0.5])
    first = obs.step(np.full(3, np.nan), u).x
    second = obs.step(np.full(3, np.nan), u).x
    np.testing.assert_allclose(first, [0.1, 0, 0, 0])
    np.testing.assert_allclose(second, model.A @ first + model.B @ u, atol=1e-15)


def test_kalman_covariance_converges_to_the_riccati_solution():
    model = masses_model()
    kf = estimators.create("kalman", model, {"measurement_std": 1e-3, "process_std": 1e-4})
    for _ in range(3000):
        kf.step(np.zeros(3), np.zeros(1))
    P = scipy.linalg.solve_discrete_are(model.A.T, model.C.T, kf.Q, kf.R)
    np.testing.assert_allclose(kf.P, P, rtol=1e-6, atol=1e-14)


def test_kalman_innovations_are_white_with_the_predicted_covariance():
    """On a plant with the assumed noise the filter is optimal: its innovations ν = y − C x̂_{k|k−1}
    are white with covariance S = C P Cᵀ + R, so the mean of νᵀ S⁻¹ ν is p (chi-square)."""
    model = masses_model()
    q, r = 1e-3, 1e-2
    kf = KalmanFilter.from_params(model, {"measurement_std": r, "process_std": q, "initial_std": 0.1})
    rng = np.random.default_rng(0)
    x = rng.normal(scale=0.1, size=4)
    nis, innovations = [], []
    for k in range(10000):
        u = np.array([math.sin(0.05 * k)])
        y = model.C @ x + r * rng.standard_normal(3)
        nu = y - model.C @ kf.x_hat
        S = model.C @ kf.P @ model.C.T + kf.R
        nis.append(nu @ np.linalg.solve(S, nu))
        innovations.append(nu / np.sqrt(np.diag(S)))
        kf.step(y, u)
        x = model.A @ x + model.B @ u + q * rng.standard_normal(4)
    # mean of 10000 chi-square(3) samples: standard error sqrt(6/10000) = 0.024
    assert np.mean(nis) == pytest.approx(3.0, abs=0.1)
    z = np.array(innovations)
    lag1 = np.mean(z[1:] * z[:-1], axis=0)  # white: ≈ 0 with standard error 0.01
    assert np.all(np.abs(lag1) < 0.05)


def test_kalman_skips_missing_rows():
    model = masses_model()
    kf = estimators.create("kalman", model, {"initial_std": 0.5})
    P0 = kf.P.copy()
    kf.step(np.full(3, np.nan), np.zeros(1))
    np.testing.assert_allclose(kf.P, model.A @ P0 @ model.A.T + kf.Q)


@pytest.mark.parametrize(
    ("kind", "params", "message"),
    [
        (
            "pseudoinverse",
            {"pole": [0.5]},
            r"pole: unknown parameter of pseudoinverse \(known: gain, min_det, poles, weights, x0\)",
        ),
        ("pseudoinverse", {"weights": [1, 1]}, r"weights: expected 3 weights \(one per output: x1, x2, x1_minus_x2\)"),
        ("pseudoinverse", {"poles": [0.5, 0.6]}, r"poles: need 4 poles"),
        ("pseudoinverse", {"x0": [1.0]}, r"x0: expected 4 values \(x1, x2, v1, v2\)"),
        ("kalman", {"measurement_std": [1, 2]}, r"measurement_std: expected one value or 3"),
        ("kalman", {"measurement_std": 0}, r"measurement_std: must be positive"),
        ("luenberger", {}, r"kind: unknown estimator 'luenberger'"),
    ],
)
def test_bad_parameters_name_the_parameter(kind, params, message):
    with pytest.raises(ParameterError, match=message):
        estimators.create(kind, masses_model(), params)


def test_pseudoinverse_needs_redundant_outputs():
    with pytest.raises(ParameterError, match=r"not redundant: rank\(C\) = 2 is not below p = 2"):
        estimators.create("pseudoinverse", masses_model(("x1", "x2")), {})


def test_schur_check():
    assert is_schur(np.diag([0.5, -0.9])) and not is_schur(np.diag([0.5, 1.0]))
