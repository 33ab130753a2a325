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
from estimators.lmi import (
    DesignError,
    SensorFaultModel,
    box_coordinates,
    box_vertices,
    max_spectral_radius,
    uio_matrices,
)
from estimators.lpv_design import lpv_uio_design
from estimators.model import LinearModel
from estimators.model_window import model_window, window_gains
from estimators.sample_window import Sample
from mjcf.three_tank import PAPER_A, PAPER_B, PAPER_C, PAPER_E
from tests.test_lmi import SMALL

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


@pytest.fixture(scope="module")
def lft_design():
    return lft_uio_design(PAPER, LOW, HIGH)


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


# -- the gain estimator on the model (ours; docs/three-tank.md) ----------------------------------


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


# -- the gain test (ours: γ̂ changes only on evidence; docs/three-tank.md, "The gain test") -----------
#
# Issue 18's requirements, on the paper's linear plant (58) with the scenario's excitation (square
# waves of ±8 cm³/s, periods 150 s and 97 s; v = 0.02 sin(2πt/90 s)) and 0.01 cm of white noise
# on every sensor, added before the gain as the testbed does (noise first, then the faults).

NOISE = 0.01
WINDOW = 50  # N, the parameter estimator's horizon (Sec. 4)


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
