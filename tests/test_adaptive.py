"""The adaptive pseudoinverse observers against their papers: TAC 2024 (discrete time) and CDC 2016
(continuous time), and the design utilities they share."""

from __future__ import annotations

import importlib.util
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

import estimators
from estimators import LinearModel, ParameterError
from estimators.adaptive import BiasEstimator
from estimators.adaptive_law import cost_matrix, line_search, line_search_coefficients, optimizer_step, select
from estimators.continuous import ObserverODE, gradient, pseudoinverse, vector_field
from estimators.design import (
    AssumptionError,
    assumption2_factorization,
    check_assumption1,
    fault_rejectable,
    observer_gain,
    output_factorization,
    zoh_discretize,
)
from mjcf import masses
from tests.linear_masses import masses_model

P3 = ("x1", "x2", "x1_minus_x2")
P4 = ("x1", "x2", "x1_minus_x2", "x2_minus_x1")


def simulate(model, phi_of_k, ests, ticks, x0=(0.2, -0.1, 0.0, 0.0)):
    """Plant (1) driven by the paper's kind of periodic input; returns errors and diagnostics per estimator."""
    x = np.array(x0, dtype=float)
    errors = {name: np.empty(ticks) for name in ests}
    diagnostics = {name: [] for name in ests}
    for k in range(ticks):
        u = np.array([math.sin(2 * math.pi * 0.5 * k * model.dt)])
        y = model.C @ x + phi_of_k(k)
        for name, e in ests.items():
            estimate = e.step(y, u)
            errors[name][k] = np.linalg.norm(x - estimate.x)
            diagnostics[name].append(estimate.diagnostics)
        x = model.A @ x + model.B @ u
    return errors, diagnostics


# -- design utilities ---------------------------------------------------------------------------


def test_assumption2_construction_on_example_1():
    """For C of eq. (3) the normalized selection (4a)-(4b) already satisfies Assumption 2: Σ = I."""
    C = masses.output_matrix(P3)
    Y, H, sigma = assumption2_factorization(C)
    r3 = math.sqrt(3)
    np.testing.assert_allclose(
        Y, np.array([[(3 + r3) / 6, (3 - r3) / 6, 1 / r3], [(3 - r3) / 6, (3 + r3) / 6, -1 / r3]]).T, atol=1e-15
    )
    np.testing.assert_allclose(
        H,
        np.array(
            [[(3 + r3) / (2 * r3), (-3 + r3) / (2 * r3), 0, 0], [(-3 + r3) / (2 * r3), (3 + r3) / (2 * r3), 0, 0]]
        ),
        atol=1e-15,
    )
    np.testing.assert_array_equal(sigma, np.eye(3))


def test_assumption2_construction_recombines_aligned_outputs():
    """A sensor no other sensor reproduces puts e₁ in Im(Y); the orthogonal Σ of the construction
    removes it: YᵀY = I, no eᵢ in Im(Y), Σ C = Y H, ΣᵀΣ = I."""
    C = np.array([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 1, 0, 0]])
    Y0, _ = output_factorization(C)
    assert np.isclose(np.max(np.linalg.norm(Y0, axis=1)), 1.0)  # e₁ ∈ Im(Y∘)
    Y, H, sigma = assumption2_factorization(C)
    np.testing.assert_allclose(Y.T @ Y, np.eye(2), atol=1e-12)
    assert np.max(np.linalg.norm(Y, axis=1)) < 1 - 1e-6
    np.testing.assert_allclose(sigma @ C, Y @ H, atol=1e-12)
    np.testing.assert_allclose(sigma.T @ sigma, np.eye(3), atol=1e-12)


def test_assumption1_failures_name_the_item():
    model = masses_model()
    check_assumption1(model.A, model.C)
    with pytest.raises(AssumptionError, match=r"not redundant.*1\.1"):
        check_assumption1(model.A, model.C[:2])
    with pytest.raises(AssumptionError, match=r"eigenvalue at 1.*1\.3"):
        check_assumption1(np.diag([1.0, 0.5]), np.array([[1.0, 0], [0, 1], [1, 1]]))
    with pytest.raises(AssumptionError, match=r"not detectable.*1\.2"):  # an unstable mode C cannot see
        check_assumption1(np.diag([1.5, 0.5]), np.array([[0.0, 1], [0, 2]]))
    with pytest.raises(ParameterError, match="model: outputs are not redundant"):
        estimators.create("adaptive", masses_model(("x1", "x2")))


def test_remark_4_bias_in_the_image_of_Y_is_flagged():
    Y, _, _ = assumption2_factorization(masses.output_matrix(P3))
    assert fault_rejectable(Y, np.array([1.0, -1.5, 0.5]))
    assert not fault_rejectable(Y, Y @ np.array([0.3, -2.0]))  # the same reading offset as a state shift


@pytest.mark.parametrize(
    "poles", [(0, 0, 0, 0), (0, 0, 0.01, 0.01), (0.5, 0.5, 0.5, 0.2), (0.3 + 0.2j, 0.3 - 0.2j, 0.3, 0.3)]
)
def test_pole_placement_with_repeated_poles(poles):
    """σ(A − M H) as asked, including multiplicities above rk H = 2 that scipy refuses."""
    model = masses_model()
    _, H = output_factorization(model.C)
    M = observer_gain(model.A, H, poles)
    np.testing.assert_allclose(np.poly(model.A - M @ H), np.real(np.poly(poles)), atol=1e-7)
    if not np.any(poles):  # dead beat: nilpotent in the fewest steps, max controllability index = 2
        assert np.linalg.norm(np.linalg.matrix_power(model.A - M @ H, 2)) < 1e-9
        assert np.abs(M).max() < 1e3


# -- TAC 2024: bias estimator, optimizer, selector -----------------------------------------------


def test_proposition_1_bias_estimate_converges_exponentially():
    model = masses_model()
    Y, H, _ = assumption2_factorization(model.C)
    M = observer_gain(model.A, H, (0.5, 0.55, 0.6, 0.65))
    bias = BiasEstimator(model.A, model.B, Y, H, M)
    phi = np.array([1.0, -1.5, 0.5])
    x, errors = np.array([0.3, -0.2, 0.1, 0.0]), []
    for k in range(200):
        u = np.array([math.sin(0.1 * k)])
        y = model.C @ x + phi
        errors.append(np.linalg.norm(bias.estimate(y) - phi))
        bias.update(y, u)
        x = model.A @ x + model.B @ u
    errors = np.array(errors)
    assert errors[-1] < 1e-10 * errors[0]
    # exponential, at the rate of the slowest pole 0.65 (up to the transient's polynomial factor)
    ratio = (errors[40] / errors[10]) ** (1 / 30)
    assert ratio < 0.7


def _random_instance(rng, p=4, q=2):
    Y = np.linalg.qr(rng.normal(size=(p, q)))[0]
    phi = rng.normal(size=p)
    z = rng.normal(size=p)
    return Y, phi, z / np.linalg.norm(z)


def test_lemma_2_gamma_nonnegative_and_line_search_minimizes():
    """γ = (β₁/2)² − β₂β₀ ≥ 0 and each candidate of (37d) minimizes f(ζ) of (36) (dense search over ζ,
    including ζ = ±∞); f′(ζ) = 2(β₂ζ² + β₁ζ + β₀)/|z + ζeᵢ|⁴, eq. (39) corrected (docs/errata.md)."""
    rng = np.random.default_rng(0)
    zetas = np.concatenate([np.linspace(-50, 50, 20001), np.tan(np.linspace(-1.5707, 1.5707, 4001))])
    for _ in range(200):
        Y, phi, z = _random_instance(rng, p=int(rng.integers(3, 6)), q=int(rng.integers(1, 3)))
        S = cost_matrix(Y, phi)
        for i in range(z.size):
            b0, b1, b2 = line_search_coefficients(z, S, i)
            assert b1 * b1 / 4 - b2 * b0 >= -1e-12 * max(1.0, b1 * b1)
            v = z[:, None] + zetas[None, :] * np.eye(z.size)[:, i : i + 1]
            v /= np.linalg.norm(v, axis=0)
            f = np.einsum("ik,ij,jk->k", v, S, v)
            best = min(f.min(), S[i, i])
            candidate = line_search(z, S, i)
            assert np.isclose(np.linalg.norm(candidate), 1.0)
            assert candidate @ S @ candidate <= best + 1e-9 * max(1.0, best)
            # eq. (39), corrected: f′(ζ) = 2(β₂ζ² + β₁ζ + β₀) / |z + ζ eᵢ|⁴ at a sample point
            zeta, d = 0.37, 1e-6

            def fz(t, z=z, S=S, i=i):
                w = z + t * np.eye(z.size)[i]
                return w @ S @ w / (w @ w)

            numeric = (fz(zeta + d) - fz(zeta - d)) / (2 * d)
            w = z + zeta * np.eye(z.size)[i]
            assert np.isclose(numeric, 2 * (b2 * zeta**2 + b1 * zeta + b0) / (w @ w) ** 2, rtol=1e-5, atol=1e-9)


def test_property_1_strict_decrease_unless_zero():
    """|Γ(φ) z⁺| < |Γ(φ) z| for z⁺ = G_z(z, φ) of (37e), unless Γ(φ) z⁺ = 0; and iterating reaches 𝒵*."""
    rng = np.random.default_rng(1)
    for _ in range(300):
        Y, phi, z = _random_instance(rng, p=int(rng.integers(3, 7)), q=2)
        gamma = Y.T * phi
        before = np.linalg.norm(gamma @ z)
        z_next = optimizer_step(z, phi, Y)
        after = np.linalg.norm(gamma @ z_next)
        assert np.isclose(np.linalg.norm(z_next), 1.0)
        assert after < before or after < 1e-12
    Y, phi, z = _random_instance(np.random.default_rng(2), p=3, q=2)
    for _ in range(500):
        z = optimizer_step(z, phi, Y)
    assert np.linalg.norm((Y.T * phi) @ z) < 1e-12


def test_selector_takes_z_only_inside_S_epsilon():
    Y, _, _ = assumption2_factorization(masses.output_matrix(P3))
    s = np.ones(3) / math.sqrt(3)
    good, singular = np.array([3, 2, -6]) / 7.0, np.array([1.0, 0, 0])  # det R(e₁) = 0 for q = 2
    assert select(s, good, Y, 0.01)[1] == 0 and np.array_equal(select(s, good, Y, 0.01)[0], good)
    held, h = select(s, singular, Y, 0.01)
    assert h == 1 and held is s


# -- TAC 2024: the observers ---------------------------------------------------------------------


def test_adaptive_observer_rejects_a_constant_bias_where_uniform_weights_cannot():
    """Sec. VII-A, Fig. 3: the error of the adaptive observer vanishes, s = z ∈ 𝒵* (Corollary 3);
    the uniform-weight observer settles on its analytic steady error (19)."""
    model = masses_model()
    phi = np.array([1.0, -1.5, 0.5])
    ests = {"adaptive": estimators.create("adaptive", model), "uniform": estimators.create("pseudoinverse", model)}
    errors, diagnostics = simulate(model, lambda k: phi, ests, 1500)
    assert errors["adaptive"][-1] < 1e-8
    assert errors["uniform"][-1] == pytest.approx(0.9187, abs=1e-3)
    last = diagnostics["adaptive"][-1]
    s = np.array([last[f"s_{o}"] for o in P3])
    z = np.array([last[f"z_{o}"] for o in P3])
    np.testing.assert_allclose(s, z)
    np.testing.assert_allclose(np.abs(s), np.array([3, 2, 6]) / 7, atol=1e-8)  # the unit kernel of Γ(φ)
    np.testing.assert_allclose([last[f"phihat_{o}"] for o in P3], phi, atol=1e-9)
    assert last["h"] == 0


def test_residual_injection_recovers_when_the_selector_refuses_z():
    """Sec. VII-B, Fig. 5 (p = 4): z settles where |det R(z)| < ε, the selector holds s (h = 1); only
    the residual-injection variant (52)-(53) converges (Corollary 4). With a smaller ε both do."""
    model = masses_model(P4)
    phi = np.array([1.0, -1.5, 0.5, 0.15])
    ests = {
        "injection": estimators.create("adaptive", model, {"epsilon": 0.01, "injection": True}),
        "plain": estimators.create("adaptive", model, {"epsilon": 0.01}),
        "plain_small_eps": estimators.create("adaptive", model, {"epsilon": 1e-3}),
        "uniform": estimators.create("pseudoinverse", model),
    }
    errors, diagnostics = simulate(model, lambda k: phi, ests, 2000)
    assert errors["injection"][-1] < 1e-8
    assert errors["plain"][-1] > 1.0
    assert errors["plain_small_eps"][-1] < 1e-8
    assert errors["uniform"][-1] > 0.5
    assert diagnostics["injection"][-1]["h"] == 1 and diagnostics["plain_small_eps"][-1]["h"] == 0


def test_injection_observer_56_is_unbiased_for_a_constant_bias():
    model = masses_model()
    phi = np.array([1.0, -1.5, 0.5])
    ests = {
        "raw": estimators.create("injection", model),
        "filtered": estimators.create("injection", model, {"filter": 0.05}),
    }
    errors, _ = simulate(model, lambda k: phi, ests, 3000)
    assert errors["raw"][-1] < 1e-8 and errors["filtered"][-1] < 1e-6


def test_missing_readings_make_open_loop_ticks():
    model = masses_model()
    e = estimators.create("adaptive", model)
    x = e.step(np.array([0.1, np.nan, 0.1]), np.zeros(1))
    assert np.all(np.isfinite(x.x)) and x.diagnostics["h"] == 0


def test_parameter_errors_are_named():
    model = masses_model()
    with pytest.raises(ParameterError, match="bias_poles"):
        estimators.create("adaptive", model, {"bias_poles": [0, 0, 0, 1.2]})
    with pytest.raises(ParameterError, match="filter"):
        estimators.create("adaptive", model, {"filter": 1.5})
    with pytest.raises(ParameterError, match="epsilon"):
        estimators.create("adaptive", model, {"epsilon": 0.5})  # |det R(uniform)| = 1/3 for q = 2
    with pytest.raises(ParameterError, match="dead_zone"):
        estimators.create("adaptive", model, {"dead_zone": -0.1})


# -- TAC 2024 under measurement noise (docs/tac2024.md, bench/adaptive_noise.py) -----------------

# bench/ is not a package: the sweep's script, loaded from its file.
_SWEEP = Path(__file__).resolve().parents[1] / "bench" / "adaptive_noise.py"
_SPEC = importlib.util.spec_from_file_location("adaptive_noise", _SWEEP)
assert _SPEC is not None and _SPEC.loader is not None
adaptive_noise = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(adaptive_noise)


def test_noise_breaks_the_papers_setting_and_not_the_tuned_one():
    """The sweep's claim on one seed: at 10 µm of noise the paper's setting (Sec. VII-A) settles
    above the uniform weights' steady error (0.92), at 1 mm tens of times above; the tuned setting
    (bias poles 0.99, ε = 0.1) at 1 mm settles two orders of magnitude below it, its peak bounded."""
    paper, tuned = adaptive_noise.SETTINGS["paper (Sec. VII-A)"], adaptive_noise.SETTINGS[adaptive_noise.TUNED_LABEL]
    uniform = adaptive_noise.measure(adaptive_noise.simulate("pseudoinverse", {}, 1e-3, 0))
    assert uniform["settled"] == pytest.approx(0.92, abs=0.02)
    assert adaptive_noise.measure(adaptive_noise.simulate(*paper, 1e-5, 0))["settled"] > uniform["settled"]
    broken = adaptive_noise.measure(adaptive_noise.simulate(*paper, 1e-3, 0))
    assert broken["settled"] > 20 * uniform["settled"]
    stable = adaptive_noise.measure(adaptive_noise.simulate(*tuned, 1e-3, 0))
    assert stable["settled"] < 0.02 * uniform["settled"]
    assert stable["peak"] < 30 and stable["rms"] < uniform["rms"]


def test_bias_estimate_noise_is_the_h2_gain_of_eq_7():
    """φ̂'s noise per unit of measurement noise, the mechanism docs/tac2024.md gives: 6.7e4 with the
    paper's bias poles (A ≈ I makes (I − A)⁻¹ in (7c) large), 3.0 with all four at 0.99; the
    analytic H₂ gain agrees with the bias estimator (7) driven by white noise."""
    model = masses_model()
    Y, H, _ = assumption2_factorization(model.C)
    rng = np.random.default_rng(0)
    for poles, gain in (((0.0, 0.0, 0.01, 0.01), 6.67e4), ((0.99,) * 4, 2.96)):
        assert adaptive_noise.bias_noise_gain(poles) == pytest.approx(gain, rel=0.01)
        bias = BiasEstimator(model.A, model.B, Y, H, observer_gain(model.A, H, poles))
        u, squares = np.zeros(1), []
        for k in range(6000):
            y = rng.standard_normal(3)
            if k >= 1000:  # past the transient
                squares.append(float(np.sum(bias.estimate(y) ** 2)))
            bias.update(y, u)
        assert math.sqrt(np.mean(squares)) == pytest.approx(gain, rel=0.1)


def test_dead_zone_holds_the_optimizer_while_no_bias_is_told_from_noise():
    """Without a bias, φ̂ is noise once the initial error has decayed (ξ and x̂ start at 0, x at
    (0.2, −0.1, 0, 0)): the paper's law (δ = 0) moves z all over the sphere, a dead zone above φ̂'s
    noise (3 σ with the tuned bias poles) holds it; with a bias from 15 s, both adapt to 𝒵*."""
    model = masses_model()
    tuned = adaptive_noise.TUNED
    ests = {
        "paper_law": estimators.create("adaptive", model, tuned),
        "dead_zone": estimators.create("adaptive", model, tuned | {"dead_zone": 0.02}),
    }
    rng = np.random.default_rng(0)
    noise = [1e-3 * rng.standard_normal(3) for _ in range(3000)]
    phi = np.array([1.0, -1.5, 0.5])
    _, diagnostics = simulate(model, lambda k: noise[k] + (phi if k >= 1500 else 0.0), ests, 3000)

    def z(name, k):
        return np.array([diagnostics[name][k][f"z_{o}"] for o in P3])

    quiet = range(1000, 1500)  # 0.99¹⁰⁰⁰ = 4e-5: the initial error is gone, no bias yet
    assert max(np.linalg.norm(z("paper_law", k) - z("paper_law", 1000)) for k in quiet) > 0.5
    assert all(np.array_equal(z("dead_zone", k), z("dead_zone", 1000)) for k in quiet)
    for name in ests:  # adapted: |Γ(φ) z| near 0 at the end, as in the noise-free case up to the noise
        assert np.linalg.norm((ests[name].Y.T * phi) @ z(name, 2999)) < 0.02


# -- CDC 2016 -------------------------------------------------------------------------------------

A_CDC = np.array([[-1.0, 3, 0], [0.1, -5, 0.4], [0, 0, -5]])
Y_CDC = np.array([[1.0, 1], [1, 0], [2, 1]])
H_CDC = np.array([[1.0, 0, 0], [0, 1, 0]])
L1 = np.array([[6, 2.7], [-0.2, -1], [-0.2, -5.1]])
L2 = np.array([[8, 2.9], [-0.1, 8], [-1.4, 37.5]])


def cdc_model() -> LinearModel:
    return LinearModel(
        A_CDC,
        np.array([[1.0], [0], [-1]]),
        Y_CDC @ H_CDC,
        np.zeros((3, 1)),
        None,
        ("x1", "x2", "x3"),
        ("u",),
        ("y1", "y2", "y3"),
    )


def test_cdc_gains_are_the_slow_and_the_fast_observer():
    """Erratum: A − L1 H has eigenvalues ≈ {−3, −6, −7} (slow), A − L2 H ≈ {−8, −9, −10} (fast)."""
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(A_CDC - L1 @ H_CDC).real), [-7, -6, -3], atol=0.05)
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(A_CDC - L2 @ H_CDC).real), [-10, -9, -8], atol=0.05)


def test_cdc_gradient_8_matches_finite_differences_and_lemma_3():
    rng = np.random.default_rng(3)
    for _ in range(50):
        gamma, y, z_hat = rng.uniform(0.2, 1, 3), rng.normal(size=3), rng.normal(size=2)

        def cost(g, y=y, z_hat=z_hat):
            return np.sum((pseudoinverse(Y_CDC, g) @ y - z_hat) ** 2)

        d = 1e-6
        numeric = np.array([(cost(gamma + d * e) - cost(gamma - d * e)) / (2 * d) for e in np.eye(3)])
        np.testing.assert_allclose(gradient(Y_CDC, gamma, y, z_hat), numeric, rtol=1e-6, atol=1e-8)
        # Lemma 3: ∂(Z_Γ φ)/∂Γ · Γ = 0 (scale invariance)
        phi = rng.normal(size=3)
        directional = (pseudoinverse(Y_CDC, gamma * (1 + d)) @ phi - pseudoinverse(Y_CDC, gamma * (1 - d)) @ phi) / (
            2 * d
        )
        np.testing.assert_allclose(directional, 0, atol=1e-8)


@pytest.mark.parametrize("q", [1, 2, 3])
def test_cdc_observer_ode_is_the_vector_field_and_its_jacobian(q):
    """The integrator's f(w) (two products and the q×q solves in closed form for q ≤ 2, numpy's for
    q = 3) is (6)–(7) of ``vector_field``; its ∂f/∂w in closed form agrees with central differences;
    det(Yᵀ G_Γ Y) is numpy's."""
    rng = np.random.default_rng(4)
    n, p = 3, q + 2
    A, B = rng.normal(size=(n, n)), rng.normal(size=(n, 1))
    Y, H, L = rng.normal(size=(p, q)), rng.normal(size=(q, n)), rng.normal(size=(n, q))
    ode = ObserverODE(A, B, H, L, Y, 3.0, 2.0)
    for _ in range(20):
        y, u = rng.normal(size=p), rng.normal(size=1)
        ode.hold(y, u)
        w = np.concatenate([rng.normal(size=n), rng.uniform(0.2, 1.0, p)])
        f, J = ode.linearized(w)
        expected = np.concatenate(vector_field(w[:n], w[n:], y, B @ u, A, H, L, Y, 3.0, 2.0))
        np.testing.assert_allclose(f, expected, rtol=0, atol=1e-13 * np.abs(expected).max())
        np.testing.assert_array_equal(ode(w), f)
        d = 1e-6
        numeric = np.array([(ode(w + d * e) - ode(w - d * e)) / (2 * d) for e in np.eye(n + p)]).T
        np.testing.assert_allclose(J, numeric, rtol=0, atol=1e-7 * np.abs(J).max())
        assert ode.weight_det(w[n:]) == pytest.approx(np.linalg.det((Y.T * w[n:]) @ Y), rel=1e-13)


def test_cdc_integration_between_samples_matches_a_tight_reference():
    """One sample interval right after a fault, stiff adaptation (κ = 10): the estimator's Rosenbrock
    integration against scipy's Radau at rtol 1e-11."""
    model = cdc_model()
    e = estimators.create(
        "adaptive-ct", model, {"gain": L1.tolist(), "Y": Y_CDC.tolist(), "kappa": 10.0}, sample_time=0.02
    )
    y = np.array([3.0, 0.5, -1.0])
    w0 = np.concatenate([e.x_hat, e.gamma])
    for _ in range(25):
        e.step(y, np.zeros(1))

    def rhs(t, w):
        return np.concatenate(vector_field(w[:3], w[3:], y, np.zeros(3), A_CDC, H_CDC, L1, Y_CDC, 10.0, 10.0))

    reference = scipy.integrate.solve_ivp(rhs, (0, 0.5), w0, method="Radau", rtol=1e-11, atol=1e-13).y[:, -1]
    np.testing.assert_allclose(np.concatenate([e.x_hat, e.gamma]), reference, rtol=2e-3, atol=1e-4)


def cdc_example(name: str) -> tuple[dict, np.ndarray]:
    """A CDC 2016 example's scenario and readings of the same kind as its run: the exact plant from
    the scenario's initial state, its uniform output noise and its bias fault, at its sample times."""
    scenario = tomllib.loads((Path(__file__).resolve().parent.parent / "scenarios" / f"{name}.toml").read_text())
    dt, fault, noise = scenario["sample_time"], scenario["faults"][0], scenario["noise"][0]["bound"]
    x = np.array(list(scenario["plant"]["initial_state"].values()))
    Ad = scipy.linalg.expm(A_CDC * dt)
    rng = np.random.default_rng(0)
    ys = []
    for k in range(round(scenario["duration"] / dt)):
        phi = np.array(fault["value"]) if k * dt >= fault["start"] - 1e-9 else 0.0
        ys.append(Y_CDC @ H_CDC @ x + phi + rng.uniform(-noise, noise, 3))
        x = Ad @ x
    return scenario, np.array(ys)


def reference_field(y, A, H, L, Y, kappa_phi: float, kappa_gamma: float):
    """(6)–(7) with y held and u = 0 (the CDC examples: q = 2), transcribed anew in Python floats for
    the reference solution: w = [x̂; Γ] ↦ [dx̂/dt; dΓ/dt]. Independent of ``vector_field`` (whose
    numpy calls cost the reference 20 ms a sample after a fault) and held against it below."""
    n, (p, q) = len(A), Y.shape
    assert q == 2
    A, H, L, Y, y = A.tolist(), H.tolist(), L.tolist(), Y.tolist(), [float(v) for v in y]
    rows = range(p)
    # what depends on y and Y alone, once per sample: Y_i0², Y_i0 Y_i1, Y_i1², Y_ij y_i
    squares = [(Y[i][0] * Y[i][0], Y[i][0] * Y[i][1], Y[i][1] * Y[i][1], Y[i][0] * y[i], Y[i][1] * y[i]) for i in rows]

    def field(t, w):
        x, gamma = w[:n].tolist(), w[n:].tolist()
        r00 = r01 = r11 = b0 = b1 = 0.0  # R = Yᵀ diag(Γ) Y and b = Yᵀ diag(Γ) y
        for g, (s00, s01, s11, t0, t1) in zip(gamma, squares):
            r00, r01, r11, b0, b1 = r00 + g * s00, r01 + g * s01, r11 + g * s11, b0 + g * t0, b1 + g * t1
        det = r00 * r11 - r01 * r01
        i00, i01, i11 = r11 / det, -r01 / det, r00 / det  # R⁻¹, symmetric
        zy = (i00 * b0 + i01 * b1, i01 * b0 + i11 * b1)
        e0 = zy[0] - sum(h * v for h, v in zip(H[0], x))
        e1 = zy[1] - sum(h * v for h, v in zip(H[1], x))
        dx = [sum(a * v for a, v in zip(A[i], x)) + L[i][0] * e0 + L[i][1] * e1 for i in range(n)]
        v0, v1 = i00 * e0 + i01 * e1, i01 * e0 + i11 * e1
        norm = 1.0 - sum(g * g for g in gamma)
        dgamma = [
            -kappa_phi * abs(det) * 2.0 * (y[i] - Y[i][0] * zy[0] - Y[i][1] * zy[1]) * (Y[i][0] * v0 + Y[i][1] * v1)
            + kappa_gamma * norm * gamma[i]
            for i in rows
        ]
        return dx + dgamma

    return field


def test_the_reference_field_is_the_vector_field():
    rng = np.random.default_rng(7)
    for _ in range(50):
        y, w = rng.normal(size=3), np.concatenate([rng.normal(size=3), rng.uniform(0.1, 1.0, 3)])
        expected = np.concatenate(vector_field(w[:3], w[3:], y, np.zeros(3), A_CDC, H_CDC, L2, Y_CDC, 10.0, 3.0))
        found = reference_field(y, A_CDC, H_CDC, L2, Y_CDC, 10.0, 3.0)(0.0, w)
        np.testing.assert_allclose(found, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())


def agreement_with_the_reference(estimator, ys: np.ndarray) -> np.ndarray:
    """max |w − w_ref| / max |w_ref| per component of w = [x̂; Γ] over the samples ys, for the
    estimator's ODE (6)–(7) integrated by Hairer's DOP853 (scipy's Fortran one, rtol 1e-10) with the
    same held readings, from the estimator's state at the first of them; in units of the estimator's
    rtol."""
    e = estimator
    w_ref = np.concatenate([e.x_hat, e.gamma])
    errors, sizes = np.zeros(w_ref.size), np.abs(w_ref)
    for y in ys:
        e.step(y, np.zeros(1))
        field = reference_field(y, A_CDC, H_CDC, e.L, e.Y, e.kappa_phi, e.kappa_gamma)
        solver = scipy.integrate.ode(field).set_integrator("dop853", rtol=1e-10, atol=1e-12, nsteps=10**6)
        w_ref = solver.set_initial_value(w_ref, 0.0).integrate(e.sample_time)
        assert solver.successful()
        errors = np.maximum(errors, np.abs(np.concatenate([e.x_hat, e.gamma]) - w_ref))
        sizes = np.maximum(sizes, np.abs(w_ref))
    return errors / sizes / e.params.rtol


def test_cdc_integration_agrees_with_the_reference_through_a_fault_onset():
    """Example 1 with the fast gain L2 and κ = 10 (the stiffest adaptation), from 59 s to 62 s: the
    onset at 60 s and the adaptation after it, within rtol of the reference solution."""
    scenario, ys = cdc_example("cdc2016-ex1")
    e = estimators.create("adaptive-ct", cdc_model(), {"gain": L2.tolist(), "Y": Y_CDC.tolist(), "kappa": 10.0}, 0.02)
    for y in ys[:2950]:
        e.step(y, np.zeros(1))
    assert np.max(agreement_with_the_reference(e, ys[2950:3100])) <= 1.0


@pytest.mark.slow
@pytest.mark.parametrize(("name", "gain"), [("cdc2016-ex1", "L2_"), ("cdc2016-ex2", "L1_")])
def test_cdc_examples_agree_with_the_reference_solution(name, gain):
    """The example's estimators of one gain with adaptation (κ > 0; the fast gain in Example 1, the
    slow one in Example 2: both gains over the two), over the whole run: x̂ and Γ within the
    scenario's rtol of the reference solution (relative to each component's largest value). The
    reference costs up to 2 ms per sample and estimator after a fault (about 200 evaluations of the
    field): one estimator of each example is 25 s; κ = 0 is the plain observer the other tests check."""
    scenario, ys = cdc_example(name)
    chosen = [s for s in scenario["estimators"] if s["name"].startswith(gain) and s["params"].get("kappa", 0.0) > 0]
    assert len(chosen) >= 1
    for spec in chosen:
        e = estimators.create("adaptive-ct", cdc_model(), spec["params"], scenario["sample_time"])
        assert np.max(agreement_with_the_reference(e, ys)) <= 1.0, spec["name"]


@pytest.mark.slow
def test_cdc_example_1_adaptation_removes_the_fault():
    """Example 1: κ = 0 keeps an error, κ = 1 and 10 remove it; final weights about equal for all."""
    model = cdc_model()
    Ad, _ = zoh_discretize(A_CDC, model.B, 0.02)
    ests = {
        (L, k): estimators.create(
            "adaptive-ct", model, {"gain": g.tolist(), "Y": Y_CDC.tolist(), "kappa": k}, sample_time=0.02
        )
        for L, g in (("L1", L1), ("L2", L2))
        for k in (0.0, 10.0)
    }
    x = np.array([1.0, -1.0, 0.5])
    final = {}
    for k in range(2000):
        y = model.C @ x + (np.array([3.0, 0.5, -1.0]) if k >= 500 else 0.0)
        for key, e in ests.items():
            estimate = e.step(y, np.zeros(1))
            final[key] = (
                np.linalg.norm(x - estimate.x),
                np.array([estimate.diagnostics[f"gamma_y{i}"] for i in (1, 2, 3)]),
            )
        x = Ad @ x
    assert final[("L1", 0.0)][0] > 3 and final[("L2", 0.0)][0] > 5
    assert final[("L1", 10.0)][0] < 1e-2 and final[("L2", 10.0)][0] < 1e-2
    np.testing.assert_allclose(final[("L1", 10.0)][1], final[("L2", 10.0)][1], atol=0.02)
    gamma = final[("L1", 10.0)][1]
    assert np.linalg.norm(pseudoinverse(Y_CDC, gamma) @ np.array([3.0, 0.5, -1.0])) < 1e-2  # h_Γ → 0
