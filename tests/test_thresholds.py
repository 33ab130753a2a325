"""Thresholds of the COFD residuals for a declared environment (estimators/thresholds.py) and the body
frame's kinematic terms (estimators/rotating_frame.py): a disturbance of the declared class never
crosses them, a fault of the stated size does, and the class is the one the vessel's environment
model draws from (mjcf/vessel.py)."""

from __future__ import annotations

import inspect

import numpy as np
import pytest
import scipy.signal

import estimators
from estimators import LinearModel, ParameterError
from estimators.allocation import VesselController, VesselControllerParams
from estimators.rotating_frame import kinematic_terms
from estimators.thresholds import DeclaredEnvironment, band_gains, centred_bounds
from mjcf.vessel import EnvironmentDisturbance, rotation
from tests.linear_vessel import THRUSTER_OF_INPUT, D, E, G, M, model, simulate

TAU = 0.1
SEA = {"current": 145.0, "wave_force": 105.0, "wave_moment": 105.0}  # |b| ≤ 294 N, the roughest under ε = 300 N
DECLARED = {"disturbance_bound": 300.0, **SEA, "model_error": 1.0, "model_error_ratio": 1e-3}


def diagnosis(**params) -> estimators.Estimator:
    return estimators.create("cofd", model(), {**DECLARED, **params}, TAU)


def filtered(F: np.ndarray, RE: np.ndarray, b, duration: float, fine: int = 20) -> np.ndarray:
    """r(t_k) = C e(t_k) of ė = F e + R E b(t), e(0) = 0, C = I (first three rows), at the ticks
    t_k = k τ, integrated exactly with b held over steps of τ / ``fine`` (close to b continuous).
    b takes an array of times; F is diagonal (the ship's): each component is a first-order filter."""
    h = TAU / fine
    forcing = b(np.arange(round(duration / TAU) * fine) * h) @ RE[:3].T  # (R E b)_i, i ≤ 3
    poles = np.diag(F)[:3]
    decay = np.exp(poles * h)
    e = np.column_stack(
        [
            scipy.signal.lfilter([0.0, (d - 1.0) / f], [1.0, -d], forcing[:, i])
            for i, (d, f) in enumerate(zip(decay, poles))
        ]
    )
    return e[::fine]


def worst_deviation(estimator, b, duration: float = 120.0) -> np.ndarray:
    """max over t ≥ t₂ of |r_i(t) − m̂_i| per observer and component, m̂ the mean of the window's ticks."""
    t1, t2 = estimator.params.learning
    ticks = np.arange(round(duration / TAU)) * TAU
    window = (ticks >= t1 - TAU / 2) & (ticks < t2 - TAU / 2)
    deviations = []
    for o in estimator.observers:
        r = filtered(o.F, o.R @ E, b, duration)
        deviations.append(np.abs(r[ticks >= t2 - TAU / 2] - r[window].mean(axis=0)).max(axis=0))
    return np.array(deviations)


def bounds(estimator) -> np.ndarray:
    """centred_bounds of every observer (without the margin)."""
    return np.array([centred_bounds(o.F, np.eye(6)[:3], o.R @ E, estimator.params, TAU) for o in estimator.observers])


def test_the_declared_class_is_the_one_the_environment_model_draws_from():
    """The defaults of the class are the environment model's, and its realizations lie in it: a
    constant current, wave periods in the band, amplitude sums, and |b| ≤ current + hypot(A, N)."""
    model_defaults = inspect.signature(EnvironmentDisturbance.random).parameters
    declared = DeclaredEnvironment(**SEA)
    assert declared.wave_periods == model_defaults["wave_periods"].default
    assert declared.swing == model_defaults["swing"].default
    assert declared.swing_period == model_defaults["swing_period"].default
    low, high = declared.band
    for seed in range(20):
        b = EnvironmentDisturbance.random(seed, **SEA)
        assert np.linalg.norm(b.current) == pytest.approx(SEA["current"])
        assert all(low - 1e-12 <= w <= high + 1e-12 for w in b.frequencies)
        assert sum(b.force_amplitudes) == pytest.approx(SEA["wave_force"])
        assert sum(b.moment_amplitudes) == pytest.approx(SEA["wave_moment"])
        assert b.bound == pytest.approx(declared.bound)
        assert b.swing * b.swing_frequency == pytest.approx(declared.turn_rate)


def test_no_realization_of_the_declared_sea_crosses_the_bound_and_a_worst_wave_comes_close():
    """Twelve sea states drawn by the environment model stay within the bound on |r_i − m̂_i| (no
    margin); a single wave of all the force at the band's longest period, along the direction of
    largest gain, reaches more than half of it: the bound is not vacuous."""
    estimator = diagnosis()
    limit = bounds(estimator)
    for seed in range(12):
        assert (worst_deviation(estimator, EnvironmentDisturbance.random(seed, **SEA)) <= limit).all(), seed
    o, component = estimator.observers[3], 1  # r4_2: T5's direction, the hardest to isolate
    low = DeclaredEnvironment(**SEA).band[0]
    response = np.linalg.solve(1j * low * np.eye(6) - o.F, o.R @ E)[component, :2]
    direction = np.real(response.conj()) / np.linalg.norm(response)  # the real direction of largest gain
    direction /= np.linalg.norm(direction)
    current = SEA["current"] * np.array([0.6, 0.8, 0.0])

    def wave(t):
        return current + SEA["wave_force"] * np.sin(low * t)[:, None] * np.array([*direction, 0.0])

    reached = worst_deviation(estimator, wave)[3, component]
    assert 0.5 * limit[3, component] < reached <= limit[3, component]


def test_the_band_gain_is_the_filtered_amplitude_of_a_wave():
    """|c_iᵀ(jωI − F)⁻¹ R E d| is the steady amplitude of r_i for b = sin(ω t) d."""
    o = diagnosis().observers[3]
    omega, d = 0.8, np.array([0.0, 1.0, 0.0])
    r = filtered(o.F, o.R @ E, lambda t: np.sin(omega * t)[:, None] * d, 60.0)
    gains, _ = band_gains(o.F, np.eye(6)[:3], (o.R @ E) @ d[:, None], (omega, omega), points=1)
    assert np.abs(r[300:]).max(axis=0) == pytest.approx(gains[0], rel=2e-3)


def test_the_waves_are_filtered_far_below_the_flat_worst_case():
    """In the roughest declared sea, T5's component r4_2 has 1.2 × 6.12 × 300 N = 2203 N s with the
    flat bound of |b| ≤ ε; around its learned mean, a third of that."""
    estimator = diagnosis()
    centred = estimator.test.centred
    assert estimator.thresholds[3, 1] == pytest.approx(2202.7, rel=1e-3)
    assert centred[3, 1] < estimator.thresholds[3, 1] / 2
    assert (centred < estimator.thresholds).all()


def step_loss(thruster: int, loss: float, onset: float):
    """Δ(t): thruster ``thruster`` (1-based) keeps 1 − loss of its effectiveness from ``onset`` on."""

    def delta(t: float) -> np.ndarray:
        per_thruster = np.ones(5)
        if t >= onset:
            per_thruster[thruster - 1] = 1.0 - loss
        return per_thruster[THRUSTER_OF_INPUT]

    return delta


@pytest.mark.parametrize("thruster", [1, 2, 3, 4, 5])
def test_a_half_loss_is_isolated_within_10_s_in_the_roughest_declared_sea(thruster):
    """On the linear model (23) in closed loop: no alarm before the onset at 20 s (the means are
    learned from 5 to 15 s), then the faulty thruster alone, within 10 s."""
    b = EnvironmentDisturbance.random(thruster, **SEA)
    controller = VesselController(M, D, G, TAU, VesselControllerParams(heading_bandwidth=0.5))
    trajectory = simulate(32.0, TAU, controller, diagnosis(), step_loss(thruster, 0.5, 20.0), b)
    before = trajectory.t < 20.0
    assert trajectory.series("alarm")[before].max() == 0
    mask = trajectory.series("fault_mask")
    assert set(mask) == {0.0, float(1 << (thruster - 1))}
    assert trajectory.t[np.flatnonzero(mask)[0]] - 20.0 <= 10.0


def test_the_residuals_are_published_around_their_learned_means_after_the_window():
    """A constant current moves r; after the window the published residual is r − m̂ (≈ 0) and the
    threshold is the centred one; before it, the raw residual against the flat threshold."""
    estimator = diagnosis()
    current = np.array([100.0, -100.0, 0.0])
    trajectory = simulate(20.0, TAU, VesselController(M, D, G, TAU), estimator, b=lambda t: current)
    r42, thr42 = trajectory.series("r4_2"), trajectory.series("thr4_2")
    early, late = trajectory.t < 14.9, trajectory.t > 15.05
    assert abs(r42[early][-1]) > 500 and thr42[early][-1] == pytest.approx(estimator.thresholds[3, 1], rel=1e-2)
    assert np.abs(r42[late]).max() < 1e-2 * abs(r42[early][-1])  # what is left of the start-up transient
    assert thr42[late][-1] == pytest.approx(estimator.test.centred[3, 1], rel=1e-2)


def test_the_inertial_allowance_follows_the_accelerations():
    """No motion, no allowance; a step of 1 m/s² in surge raises every threshold (margin × ρ × |M ν̇|
    filtered) and it decays once the acceleration stops."""
    estimator = diagnosis()
    y = np.array([0.0, 0.0, 0.0, 2.0, 1.0, 0.0])
    quiet = estimator.test.allowance(y)
    pushed = estimator.test.allowance(y + np.array([0.0, 0.0, 0.0, 0.1, 0.0, 0.0]))
    assert np.abs(quiet).max() == 0
    assert (pushed > 0).all()
    for _ in range(100):
        later = estimator.test.allowance(y + np.array([0.0, 0.0, 0.0, 0.1, 0.0, 0.0]))
    assert (later < 1e-3 * pushed).all()


@pytest.mark.parametrize(
    ("change", "field", "words"),
    [
        ({"current": 250.0}, "disturbance_bound", "raise disturbance_bound"),
        ({"wave_force": -1.0}, "wave_force", "at least 0"),
        ({"wave_periods": [10.0, 6.0]}, "wave_periods", "shortest, longest"),
        ({"learning": [15.0, 5.0]}, "learning", "start, end"),
        ({"swing_period": 0.0}, "swing_period", "positive"),
    ],
)
def test_bad_declarations_name_the_parameter(change, field, words):
    with pytest.raises(ParameterError) as error:
        diagnosis(**change)
    assert error.value.parameter == field and words in str(error.value)


def test_the_rotating_frame_needs_the_vessels_outputs():
    assert diagnosis(rotating_frame=True).frame is not None
    ship = model()
    outputs = ("a", "b", "c", "d", "e", "f")
    renamed = LinearModel(
        ship.A, ship.B, ship.C, ship.D, None, ship.states, ship.inputs, outputs, E=E, disturbances=("bx", "by", "bn")
    )
    with pytest.raises(ParameterError) as error:
        estimators.create("cofd", renamed, {"rotating_frame": True}, TAU)
    assert error.value.parameter == "rotating_frame" and "x, y, psi, u, v, r" in str(error.value)


def test_the_kinematic_terms_are_the_rotating_frames():
    """φ(y) is the exact derivative of y minus the linear model's at ψ = 0: η̇ − ν and
    d/dt Pᵀ(ψ) v_w − Pᵀ(ψ) v̇_w for an earth-frame velocity v_w held constant while the hull turns."""
    psi, r = 0.3, 0.02
    v_w = np.array([1.5, -0.7])
    nu = rotation(psi)[:2, :2].T @ v_w
    y = np.array([10.0, 20.0, psi, *nu, r])
    phi = kinematic_terms(y)
    assert phi[:2] == pytest.approx(rotation(psi)[:2, :2] @ nu - nu)
    h = 1e-6
    turning = (rotation(psi + r * h)[:2, :2].T @ v_w - rotation(psi - r * h)[:2, :2].T @ v_w) / (2 * h)
    assert phi[3:5] == pytest.approx(turning, rel=1e-6)
    assert phi[2] == phi[5] == 0.0
