"""Sensor reconciliation with UIOs (IJC 2018): the UIO algebra, the LFT, the LMI designs of
Theorems 1 and 2 with their certificates, the parameter estimator (53) and Algorithms 1 and 2,
on the paper's own discrete-time three-tank model (58)–(59)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

import estimators
from estimators.base import ParameterError
from estimators.lft_design import lft_uio_design, sensor_fault_lft
from estimators.lmi import DesignError, box_coordinates, box_vertices, max_spectral_radius, uio_matrices
from estimators.lpv_design import lpv_uio_design
from estimators.model import LinearModel
from estimators.sample_window import Sample
from tests.paper_three_tank import HIGH, HZ, LOW, PAPER, A, B, C, F, paper_lft_design, paper_model, simulate
from tests.test_lmi import SMALL


@pytest.fixture(scope="module")
def lft_design():
    return paper_lft_design()


def random_gammas(count, low=0.01, high=1.0, seed=0):
    return low + (high - low) * np.random.default_rng(seed).random((count, 4))


@pytest.mark.parametrize("form", ["pinv", "lft"])
def test_uio_matrices_satisfy_eq_11_and_12(form):
    for gamma in random_gammas(50):
        Q, T = uio_matrices(PAPER, gamma, form=form)
        np.testing.assert_allclose(T + Q @ PAPER.Cbar(gamma), np.eye(4), atol=1e-12)  # (11)
        np.testing.assert_allclose(T @ PAPER.Ebar, 0.0, atol=1e-12)  # (12)


def test_cbar_e_is_delta_g():
    """Sec. 4: C̄_γ Ē = Δ(γ) G with G = [10, 1, 1, 3]ᵀ, and C̄_γ as printed in (60)."""
    np.testing.assert_array_equal(PAPER.G[:, 0], [10, 1, 1, 3])
    gamma = np.array([0.2, 0.4, 0.6, 0.8])
    np.testing.assert_allclose(PAPER.Cbar(gamma) @ PAPER.Ebar, gamma[:, None] * PAPER.G)
    expected = [[2, 0, 0, 1], [0.4, 0, 0, 1], [0, 0.6, 0, 1], [0.8, 0.8, 0.8, 1]]
    np.testing.assert_allclose(PAPER.Cbar(gamma), expected)


def test_lft_represents_t_and_cbar_exactly_with_unit_bounded_theta():
    lft = sensor_fault_lft(PAPER, np.full(4, 0.01), HIGH)
    for gamma in random_gammas(50, seed=1):
        a, b = (1 / 0.01 + 1) / 2, (1 / 0.01 - 1) / 2
        delta_T = (1 / gamma - a) / b
        delta_C = (gamma - 0.505) / 0.495
        assert np.all(np.abs(delta_T) <= 1) and np.all(np.abs(delta_C) <= 1)
        np.testing.assert_allclose(
            lft.T11 + lft.T12 @ np.diag(delta_T) @ lft.T21, uio_matrices(PAPER, gamma, form="lft")[1], atol=1e-10
        )
        np.testing.assert_allclose(lft.C11 + lft.C12 @ np.diag(delta_C) @ lft.C21, PAPER.Cbar(gamma), atol=1e-12)


def test_box_coordinates_are_an_exact_embedding_of_cbar():
    vertices = box_vertices(LOW, HIGH)
    assert vertices.shape == (16, 4)
    for gamma in random_gammas(20, 0.5, 1.0, seed=2):
        rho = box_coordinates(gamma, LOW, HIGH)
        assert rho.min() >= 0 and abs(rho.sum() - 1) < 1e-12
        np.testing.assert_allclose(rho @ vertices, gamma, atol=1e-12)
        np.testing.assert_allclose(
            np.tensordot(rho, [PAPER.Cbar(v) for v in vertices], axes=1), PAPER.Cbar(gamma), atol=1e-12
        )


def test_lft_design_certificate(lft_design):
    """Theorem 2: the LMI (42) holds at the solution (rebuilt here with numpy), L = Q⁻¹S, and the
    error dynamics T_γ Ā − L C̄_γ are Schur on Γ."""
    d = lft_design
    assert d.min_eigenvalue > 0 and np.isfinite(d.sigma) and d.sigma > 0
    lft = sensor_fault_lft(PAPER, LOW, HIGH)
    Ab, Fb = PAPER.Abar, PAPER.Fbar
    Q, S, lam, mu = d.Q, d.Q @ d.L, float(d.lam[0]), d.mu
    Cqx = np.vstack([lft.T21 @ Ab, lft.C21])
    Fe = np.hstack([lft.T11 @ Fb, np.eye(4)])
    Fw = np.zeros((8, 5))
    Fw[:4, :1] = lft.T21 @ Fb
    r1 = [Q, Q @ lft.T11 @ Ab - S @ lft.C11, np.hstack([Q @ lft.T12, -S @ lft.C12]), Q @ Fe]
    M = np.block(
        [
            r1,
            [r1[1].T, Q - np.eye(4) - lam * Cqx.T @ Cqx, np.zeros((4, 8)), -lam * Cqx.T @ Fw],
            [r1[2].T, np.zeros((8, 4)), lam * np.eye(8), np.zeros((8, 5))],
            [r1[3].T, -lam * Fw.T @ Cqx, np.zeros((5, 8)), mu * np.eye(5) - lam * Fw.T @ Fw],
        ]
    )
    assert np.linalg.eigvalsh((M + M.T) / 2).min() > 0
    assert max_spectral_radius(PAPER, lambda g: d.L, LOW, HIGH, form="lft") < 1


def test_lft_error_system_meets_the_hinf_bound(lft_design):
    """(40): for the uncertain error system (37)–(39) with θ varying arbitrarily in |θ| ≤ 1 and
    any w ∈ ℓ2, ‖e‖ < σ ‖w‖ from e(0) = 0."""
    d, lft = lft_design, sensor_fault_lft(PAPER, LOW, HIGH)
    Ab, Fb, L = PAPER.Abar, PAPER.Fbar, lft_design.L
    N = lft.T11 @ Ab - L @ lft.C11
    Ne = np.hstack([lft.T12, -L @ lft.C12])
    Fe = np.hstack([lft.T11 @ Fb, np.eye(4)])
    Cqx = np.vstack([lft.T21 @ Ab, lft.C21])
    Fw = np.zeros((8, 5))
    Fw[:4, :1] = lft.T21 @ Fb
    rng = np.random.default_rng(3)
    for trial in range(20):
        e, e2, w2 = np.zeros(4), 0.0, 0.0
        for k in range(300):
            w = rng.normal(size=5) * (k < 100)
            theta = rng.uniform(-1, 1, 8) if trial % 2 else np.sign(rng.normal(size=8))
            q = Cqx @ e + Fw @ w
            e2, w2 = e2 + e @ e, w2 + w @ w
            e = N @ e + Ne @ (theta * q) + Fe @ w
        assert np.sqrt(e2) < d.sigma * np.sqrt(w2)


def test_diagonal_multipliers_never_do_worse(lft_design):
    diagonal = lft_uio_design(PAPER, LOW, HIGH, multiplier="diagonal")
    assert diagonal.mu <= lft_design.mu * (1 + 1e-6)


def test_theorem_2_is_infeasible_on_the_papers_full_box():
    """Recorded in docs/three-tank.md: on Γ = [0.01, 1]^4 no constant gain passes (42)."""
    with pytest.raises(DesignError, match="infeasible"):
        lft_uio_design(PAPER, np.full(4, 0.01), HIGH)


def test_lpv_design_on_a_small_plant_certifies_the_scheduled_observer():
    """Theorem 1 on a 2-state plant with 3 sensors (8 vertices): every LMI holds at the solution and,
    with the parameter switching arbitrarily between ticks, the Lyapunov decrease (29) holds for
    V = eᵀP(ρ̂)e with the scheduled gain L(ρ̂) = G(ρ̂)⁻¹Y(ρ̂)."""
    model = SMALL
    low, high = np.full(3, 0.5), np.ones(3)
    design = lpv_uio_design(model, low, high)
    assert design.min_eigenvalue > 0 and design.P.shape == (8, 3, 3)
    assert max_spectral_radius(model, design.gain, low, high) < 1
    rng = np.random.default_rng(4)
    Ab, Fb = model.Abar, model.Fbar
    for _ in range(200):
        g_now, g_next = low + (high - low) * rng.random((2, 3))
        rho, varrho = box_coordinates(g_now, low, high), box_coordinates(g_next, low, high)
        T = np.tensordot(rho, design.T, axes=1)
        Cb = np.tensordot(rho, design.C, axes=1)
        L = design.gain(g_now)
        Nm = T @ Ab - L @ Cb
        Fm = np.hstack([T @ Fb, np.eye(3)])
        P_now, P_next = np.tensordot(rho, design.P, axes=1), np.tensordot(varrho, design.P, axes=1)
        e, w = rng.normal(size=3), rng.normal(size=4)
        e_next = Nm @ e + Fm @ w
        assert e_next @ P_next @ e_next - e @ P_now @ e < -e @ e + design.mu * w @ w + 1e-9


def test_parameter_estimator_solves_the_qp_53():
    est = estimators.create("lft-uio-sr", paper_model(), {"Hz": HZ, "design_gamma_min": 0.5, "window": 20})
    rng = np.random.default_rng(5)
    for _ in range(10):
        est.history.clear()
        for _ in range(20):
            est.history.append(
                Sample(rng.normal(size=4) * 3, rng.normal(size=3), rng.normal(size=1), np.zeros(4), np.zeros(3))
            )
        gamma = est._estimate_gamma()
        ys, xs, bs = (np.array(c) for c in list(zip(*est.history))[:3])
        phi = np.vstack([np.diag(C @ x) for x in xs])
        Y = np.concatenate([y - F[:, 0] * b for y, b in zip(ys, bs)])
        reference = lsq_linear(phi, Y, bounds=(0.5, 1.0), method="bvls").x
        np.testing.assert_allclose(gamma, reference, atol=1e-9)


def test_bias_is_rejected_and_the_virtual_output_recovered(lft_design):
    """With healthy gains the UIO estimates the bias: ẑ → z while H_z y is off by H_z F b. (The
    LPV observer is checked on the three-tank scenario's log: its 4-sensor design takes a minute.)"""
    est = estimators.create(
        "lft-uio-sr", paper_model(), {"Hz": HZ, "design_gamma_min": 0.5, "L": lft_design.L.tolist()}
    )
    rows = simulate(est, 600, lambda k: np.ones(4), lambda k: 2.0 * (k >= 200))
    z_err = np.array([r[1] for r in rows[400:]])
    raw = np.array([r[2] for r in rows[400:]])
    assert np.sqrt(np.mean(z_err**2)) < 0.01 * np.sqrt(np.mean(raw**2))
    assert abs(rows[-1][3]["bhat"] - 2.0) < 1e-3


def test_remark_3_exact_gains_give_exact_estimates(lft_design):
    """With γ̂ = γ the error converges to zero (Remark 3), and the estimator (53) then returns γ."""
    est = estimators.create(
        "lft-uio-sr", paper_model(), {"Hz": HZ, "design_gamma_min": 0.5, "L": lft_design.L.tolist()}
    )
    true = np.array([0.6, 0.75, 1.0, 1.0])
    rows = simulate(est, 800, lambda k: np.where(k >= 100, true, 1.0), lambda k: 2.0 * (k >= 50), oracle=True)
    assert max(r[0] for r in rows[600:]) < 1e-6
    est.gamma = est._estimate_gamma()
    np.testing.assert_allclose(est.gamma, true, atol=1e-6)


def test_persistence_of_excitation_is_reported():
    est = estimators.create("lft-uio-sr", paper_model(), {"Hz": HZ, "design_gamma_min": 0.5, "window": 10})
    for _ in range(12):
        estimate = est.step(np.zeros(4), np.zeros(2))  # nothing moves: rank X̂_p = 0 < n, condition (55) fails
    assert estimate.diagnostics["pe"] == 0.0


def test_no_reconciliation_is_the_raw_virtual_output():
    est = estimators.create("no-reconciliation", paper_model(), {"Hz": HZ})
    y = np.array([10.0, 1.2, 3.0, 5.0])
    out = est.step(y, np.zeros(2))
    assert out.diagnostics["zhat"] == pytest.approx(np.dot(HZ, y))
    np.testing.assert_allclose(out.x, np.linalg.lstsq(C, y, rcond=None)[0])


@pytest.mark.parametrize(
    "params, message",
    [
        ({}, "Hz: required"),
        ({"Hz": HZ, "gamma_min": 0.0}, "gamma_min"),
        ({"Hz": HZ, "design_gamma_min": 0.001}, "design_gamma_min"),
        ({"Hz": HZ, "window": 1}, "window"),
        ({"Hz": HZ, "multiplier": "full"}, "multiplier"),
        ({"Hz": HZ, "gain_estimator": "kalman"}, "gain_estimator"),
        ({"Hz": HZ[:3]}, "Hz: expected 4 values"),
    ],
)
def test_bad_parameters_are_named(params, message):
    with pytest.raises(ParameterError, match=message):
        estimators.create("lft-uio-sr", paper_model(), params)


def test_a_plant_without_unknown_input_is_refused():
    model = LinearModel(A, B, C, np.zeros((4, 2)), 1.0, ("h1", "h2", "h3"), ("Q1", "Q2"), ("y1", "y2", "y3", "y4"))
    with pytest.raises(ParameterError, match="needs E"):
        estimators.create("lft-uio-sr", model, {"Hz": HZ})


def test_the_runner_caches_designs(tmp_path, monkeypatch):
    """A design is solved once: the second build reads the stored gain, identical to the first."""
    from cosim import design_cache

    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path))
    params = {"Hz": HZ, "design_gamma_min": 0.5}
    assert design_cache.load("lft-uio-sr", params, paper_model()) is None
    first = estimators.create("lft-uio-sr", paper_model(), params)
    design_cache.store("lft-uio-sr", params, paper_model(), first.design_params())
    cached = design_cache.load("lft-uio-sr", params, paper_model())
    assert cached == first.design_params()
    second = estimators.create("lft-uio-sr", paper_model(), {**params, **cached})
    assert second.design is None and np.array_equal(second.L, first.L)
    # Parameters the design does not depend on share it; those it depends on do not.
    assert (
        design_cache.load(
            "lft-uio-sr", {**params, "gain_estimator": "model", "window": 80, "fit_tol": 0.2}, paper_model()
        )
        == cached
    )
    assert design_cache.load("lft-uio-sr", {**params, "design_gamma_min": 0.6}, paper_model()) is None
    # Another version of the design code (or of the solvers) solves it again: an LMI has many solutions.
    monkeypatch.setattr(design_cache, "design_code", lambda cls: "other code")
    assert design_cache.load("lft-uio-sr", params, paper_model()) is None
    monkeypatch.setenv("COSIM_CACHE_DIR", "off")
    assert design_cache.load("lft-uio-sr", params, paper_model()) is None
