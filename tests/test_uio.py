"""The unknown input observer of the course notes (Practical Assignment 9): the worked example's
printed numbers (14)–(15), the existence conditions of eq. (8), decoupling of d and detection of
sensor and actuator faults through the residual (10), (12), in process and end to end."""

from __future__ import annotations

import numpy as np
import pytest

import estimators
from cosim import scenario
from cosim.analysis.series import load as load_series
from cosim.run import run
from estimators import LinearModel, ParameterError
from estimators.base import DiagnosticKind
from estimators.design import zoh_discretize
from estimators.uio import UIOConditionError, uio_design, uio_gains

# eq. (13)
A = np.array([[0.0, 1.0, 0.0], [-2.0, -3.0, 0.0], [0.0, 0.0, -2.0]])
B = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 1.0]])
E = np.array([[2.0], [0.0], [0.5]])
C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
# eq. (14)-(15) as printed
H_PRINTED = np.array([[0.94, 0.23], [0.0, 0.0], [0.23, 0.05]])
T_PRINTED = np.array([[0.05, 0.0, -0.23], [0.0, 1.0, 0.0], [-0.23, 0.0, 0.94]])
K1_PRINTED = np.array([[1.97, 0.32], [-2.04, -0.02], [-0.16, -0.86]])
K2_PRINTED = np.array([[-1.82, -0.45], [0.04, 0.01], [-0.08, -0.02]])
F_PRINTED = np.array([[-1.97, 0.05, 0.14], [0.04, -3.0, 0.02], [0.16, -0.23, -1.02]])

TAU = 0.01


def truncated(M: np.ndarray) -> np.ndarray:
    """M cut (toward zero) to two decimals, as the notes print their matrices."""
    return np.trunc(np.round(M * 100, 9)) / 100


def model() -> LinearModel:
    return LinearModel(
        A, B, C, np.zeros((2, 2)), None, ("x1", "x2", "x3"), ("u1", "u2"), ("y1", "y2"), E=E, disturbances=("d",)
    )


# -- the worked example (13)-(16) ----------------------------------------------------------------


def test_H_and_T_are_the_printed_ones():
    """eq. (14), with H = E (CE)⁺ from eq. (8). The notes truncate to two decimals: H₃₃ = T₁₁ =
    1/17 = 0.0588 is printed 0.05."""
    H, T = uio_gains(C, E)
    np.testing.assert_array_equal(truncated(H), H_PRINTED)
    np.testing.assert_array_equal(truncated(T), T_PRINTED)
    np.testing.assert_allclose(H @ C @ E, E, atol=1e-14)  # E − HCE = 0, the last line of (7)
    np.testing.assert_allclose(T @ E, 0.0, atol=1e-14)


def test_the_printed_K1_gives_the_printed_F_and_K2_to_one_unit_in_the_last_digit():
    """eq. (15): F = TA − K1 C and K2 = F H from the printed K1 differ from the printed F and K2 by
    at most 0.0106 (F₁₃: 0.1506 against 0.14; K2₃₁: −0.090 against −0.08), since the printed K1 is
    itself cut to two decimals; F is Hurwitz with σ(F) ≈ {−1, −2, −3}."""
    design = uio_design(A, B, C, E, K1=K1_PRINTED)
    F = design.F
    assert np.abs(F - F_PRINTED).max() == pytest.approx(0.0106, abs=1e-4)
    assert np.abs(F - F_PRINTED).max() < 0.011
    np.testing.assert_allclose(design.K2, F @ design.H, atol=1e-15)
    assert np.abs(design.K2 - K2_PRINTED).max() < 0.011
    assert np.abs(F_PRINTED @ design.H - K2_PRINTED).max() < 0.011  # K2 = F H with the printed F as well
    eigenvalues = np.sort(np.linalg.eigvals(F).real)
    np.testing.assert_allclose(eigenvalues, [-3.0, -2.0, -1.0], atol=0.01)
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(F_PRINTED).real), [-3.0, -2.0, -1.0], atol=0.01)


def test_the_printed_digits_are_one_design_placing_minus_1_2_3_truncated():
    """A witness that (14)-(15) are consistent: this K1 places σ(F) = {−1, −2, −3} (to 1e-5), and
    its K1, F = TA − K1 C and K2 = F H, cut to two decimals, are every printed digit of (15)."""
    K1 = np.array([[1.97882, 0.32444], [-2.04128, -0.02490], [-0.16529, -0.86118]])
    design = uio_design(A, B, C, E, K1=K1)
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(design.F).real), [-3.0, -2.0, -1.0], atol=1e-5)
    np.testing.assert_array_equal(truncated(K1), K1_PRINTED)
    np.testing.assert_array_equal(truncated(design.F), F_PRINTED)
    np.testing.assert_array_equal(truncated(design.K2), K2_PRINTED)


def test_pole_placement_and_the_decoupling_conditions_7():
    d = uio_design(A, B, C, E, poles=[-1.0, -2.0, -3.0])
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(d.F).real), [-3.0, -2.0, -1.0], atol=1e-9)
    I = np.eye(3)
    np.testing.assert_allclose(A - d.K1 @ C - d.H @ C @ A - d.F, 0.0, atol=1e-12)
    np.testing.assert_allclose((A - d.K1 @ C - d.H @ C @ A) @ d.H - d.K2, 0.0, atol=1e-12)
    np.testing.assert_allclose(B - d.T @ B - d.H @ C @ B, 0.0, atol=1e-12)
    np.testing.assert_allclose(E - d.H @ C @ E, 0.0, atol=1e-12)
    np.testing.assert_allclose(d.T, I - d.H @ C)


# -- existence conditions -----------------------------------------------------------------------


def test_rank_condition_is_a_clear_error():
    """A disturbance on x2 only (unmeasured): CE = 0, rank(CE) = 0 < rank(E) = 1."""
    E_bad = np.array([[0.0], [1.0], [0.0]])
    with pytest.raises(UIOConditionError, match=r"rank\(CE\) = 0 < rank\(E\) = 1") as info:
        uio_design(A, B, C, E_bad, poles=[-1, -2, -3])
    assert info.value.condition == "rank"
    with pytest.raises(ParameterError, match=r"^E: rank\(CE\) = 0 < rank\(E\) = 1.*Measure a state") as info:
        estimators.create("uio", model(), {"poles": [-1, -2, -3], "E": E_bad.tolist()}, TAU)
    assert info.value.parameter == "E"


def two_states(b: float):
    """ẋ1 = x2 + d, ẋ2 = −x1 + b x2, y = x1: (TA, C) has the unobservable mode b (the zero of (A, E, C))."""
    A2 = np.array([[0.0, 1.0], [-1.0, b]])
    return LinearModel(
        A2,
        np.array([[0.0], [1.0]]),
        np.array([[1.0, 0.0]]),
        np.zeros((1, 1)),
        None,
        ("x1", "x2"),
        ("u",),
        ("y",),
        E=np.array([[1.0], [0.0]]),
        disturbances=("d",),
    )


def test_detectability_condition_is_a_clear_error():
    m = two_states(1.0)
    with pytest.raises(UIOConditionError, match=r"\(TA, C\) is not detectable: the mode\(s\) 1 of TA") as info:
        uio_design(m.A, m.B, m.C, m.E, poles=[-1, -2])
    assert info.value.condition == "detectability"
    with pytest.raises(ParameterError, match=r"^model: \(TA, C\) is not detectable.*Add a sensor") as info:
        estimators.create("uio", m, {"poles": [-1, -2]}, TAU)
    assert info.value.parameter == "model"


def test_detectable_but_not_observable_keeps_the_fixed_mode():
    """b = −2: F keeps −2 whatever K1; the poles must list it, or give only the placeable one."""
    m = two_states(-2.0)
    for poles in ([-2.0, -5.0], [-5.0]):
        d = uio_design(m.A, m.B, m.C, m.E, poles=poles)
        np.testing.assert_allclose(np.sort(np.linalg.eigvals(d.F).real), [-5.0, -2.0], atol=1e-9)
    with pytest.raises(ValueError, match=r"detectable but not observable: F keeps the modes \[\(-2"):
        uio_design(m.A, m.B, m.C, m.E, poles=[-1.0, -5.0])


def test_parameter_errors():
    no_e = LinearModel(A, B, C, np.zeros((2, 2)), None, ("x1", "x2", "x3"), ("u1", "u2"), ("y1", "y2"))
    with pytest.raises(ParameterError, match=r"^E: the model has no unknown input"):
        estimators.create("uio", no_e, {"poles": [-1, -2, -3]}, TAU)
    assert estimators.create("uio", no_e, {"poles": [-1, -2, -3], "E": E.tolist()}, TAU).E.tolist() == E.tolist()
    with pytest.raises(ParameterError, match=r"^poles: give exactly one of poles"):
        estimators.create("uio", model(), {}, TAU)
    with pytest.raises(ParameterError, match=r"^poles: .*negative real part"):
        estimators.create("uio", model(), {"poles": [1, -2, -3]}, TAU)
    with pytest.raises(ParameterError, match=r"^K1: K1 must have shape \(3, 2\)"):
        estimators.create("uio", model(), {"K1": [[1.0, 2.0]]}, TAU)
    with pytest.raises(ParameterError, match=r"^y_hold: "):
        estimators.create("uio", model(), {"poles": [-1, -2, -3], "y_hold": "cubic"}, TAU)
    with pytest.raises(ParameterError, match=r"^model: uio needs a continuous-time model"):
        estimators.create(
            "uio",
            LinearModel(
                A, B, C, np.zeros((2, 2)), TAU, ("x1", "x2", "x3"), ("u1", "u2"), ("y1", "y2"), E=E, disturbances=("d",)
            ),
            {"poles": [-1, -2, -3]},
            TAU,
        )


# -- in-process simulation ----------------------------------------------------------------------


def simulate(d, *, sensor_fault=None, actuator_fault=None, seconds=30.0, params=None, missing=()):
    """The plant (13) sampled exactly (u and d held over τ, as the co-simulation does) with
    x(0) = (1, 0, −1), the UIO starting at 0. Returns t, residuals r_k, errors e_k, the estimator."""
    estimator = estimators.create("uio", model(), params or {"poles": [-1.0, -2.0, -3.0]}, TAU)
    Ad, BEd = zoh_discretize(A, np.hstack([B, E]), TAU)
    x = np.array([1.0, 0.0, -1.0])
    ts, rs, es = [], [], []
    for k in range(round(seconds / TAU)):
        t = k * TAU
        u = np.array([np.sin(2 * np.pi * 0.2 * t), np.sin(2 * np.pi * 0.1 * t)])
        y = C @ x + (sensor_fault(t) if sensor_fault else 0.0)
        if k in missing:
            y = np.array([np.nan, y[1]])
        estimate = estimator.step(y, u)
        ts.append(t)
        rs.append([estimate.diagnostics["r_y1"], estimate.diagnostics["r_y2"]])
        es.append(x - estimate.x)
        u_eff = u + (actuator_fault(t) if actuator_fault else 0.0)
        x = Ad @ x + BEd @ np.concatenate([u_eff, [d(t)]])
    return np.array(ts), np.array(rs), np.array(es), estimator


def SINE(t):
    return 2.0 * np.sin(2 * np.pi * 0.5 * t)


def STEPS(t):
    return [1.5, -1.0, 0.5, -2.0][int(t // 3.5) % 4]  # piecewise constant, jumps every 3.5 s


@pytest.mark.parametrize("d", [SINE, STEPS], ids=["sinusoidal", "piecewise-constant"])
def test_error_and_residual_vanish_whatever_d(d):
    """eq. (6): e → 0 at the rate of F (slowest pole −1) whatever d; after 15 s the transient
    (1.4 e^(−t) < 5e-7) is gone and what is left is the sampling floor, O(τ²) with y interpolated
    linearly between samples: |r| < 2e-5 and |e| < 4e-5 at τ = 0.01 s (measured 1.0e-5 and 2.2e-5
    for the steps, 9.1e-6 and 1.8e-5 for the sine of amplitude 2). The floor does not come from d:
    it is the same without d (y(t) is not linear between samples)."""
    t, r, e, _ = simulate(d)
    late = t >= 15.0
    assert np.abs(r[late]).max() < 2e-5
    assert np.linalg.norm(e[late], axis=1).max() < 4e-5
    assert np.linalg.norm(e[t < 0.5], axis=1).max() > 0.5  # it did start off


def test_zero_order_hold_of_y_leaves_an_order_tau_floor():
    """y held at y_{k−1} between samples (exact only for piecewise-constant y): |r| = 3.8e-3 at τ = 0.01 s."""
    t, r, _, _ = simulate(SINE, params={"poles": [-1.0, -2.0, -3.0], "y_hold": "zero-order"})
    floor = np.abs(r[t >= 15.0]).max()
    assert 1e-3 < floor < 2e-2


def test_a_sensor_fault_shows_in_the_residual():
    """eq. (9)-(10), f_s = 0.5 on y2 from 10 s: r jumps at once by (I − C H) f_s (x̂ = z + H y takes
    H f_s of it), then settles at (I + C F⁻¹ K1) f_s, since ė = F e − K1 f_s."""
    f_s = np.array([0.0, 0.5])
    t, r, _, estimator = simulate(STEPS, sensor_fault=lambda t: f_s if t >= 10.0 else 0.0, seconds=25.0)
    d = estimator.design
    onset = int(np.argmax(t >= 10.0))
    assert np.abs(r[:onset][t[:onset] >= 8.0]).max() < 1e-3  # before: transient tail + floor
    np.testing.assert_allclose(r[onset], (np.eye(2) - C @ d.H) @ f_s, atol=0.01)
    assert np.linalg.norm(r[onset]) > 0.4  # detected at the first faulty sample, threshold 0.05
    np.testing.assert_allclose(r[-1], (np.eye(2) + C @ np.linalg.solve(d.F, d.K1)) @ f_s, atol=1e-4)


def test_an_actuator_fault_shows_in_the_residual():
    """eq. (11)-(12), f_a = 2 on u1 from 10 s: ė = F e + T B f_a, so e → −F⁻¹ T B f_a and
    r = C e → −C F⁻¹ T B f_a. C T B e₁ = 0, so r grows like t² at first: |r| crosses 0.05 after
    about a quarter of a second."""
    f_a = np.array([2.0, 0.0])
    t, r, e, estimator = simulate(SINE, actuator_fault=lambda t: f_a if t >= 10.0 else 0.0, seconds=25.0)
    d = estimator.design
    steady = -np.linalg.solve(d.F, d.T @ B @ f_a)
    np.testing.assert_allclose(e[-1], steady, atol=1e-4)
    np.testing.assert_allclose(r[-1], C @ steady, atol=1e-4)
    assert np.linalg.norm(C @ steady) > 0.5
    crossing = t[(t >= 10.0) & (np.linalg.norm(r, axis=1) > 0.05)][0] - 10.0
    assert 0.1 < crossing < 0.5


def test_a_missing_reading_holds_the_last_one():
    _, r, e, _ = simulate(SINE, missing=range(1500, 1510), seconds=20.0)
    assert np.all(np.isfinite(r)) and np.all(np.isfinite(e))
    assert np.linalg.norm(e[-1]) < 1e-3  # and the observer recovers


# -- end to end ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    out = tmp_path_factory.mktemp("uio") / "uio.mcap"
    result = run(scenario.load("uio-fault-detection"), out)
    assert result.status == "completed" and result.frames_lost == 0, result.error
    return load_series(out)


@pytest.mark.slow
def test_uio_fault_detection_end_to_end(log):
    """The scenario's description: sensor fault +0.5 on y2 in [10, 20) s, actuator fault +2 on u1
    from 30 s, d = sine + square wave all along. Threshold on |r|: 0.05."""
    _, r = log.diagnostic("uio", DiagnosticKind.RESIDUAL)
    ks = np.array(sorted(k for k in log.estimators["uio"].values if "r_y1" in log.estimators["uio"].values[k]))
    t = ks * log.sample_time
    norm = np.linalg.norm(r, axis=1)
    _, e_uio = log.error("uio")
    _, e_kalman = log.error("kalman")
    healthy = (t >= 8.0) & (t < 10.0)
    # before the first fault, despite d: residual and state error at the transient's tail (e^(−t)), below 1e-3
    assert norm[healthy].max() < 1e-3
    assert e_uio[healthy].max() < 1e-3
    # the Kalman filter, which does not know d, does not get there
    assert np.sqrt(np.mean(e_kalman[healthy] ** 2)) > 0.05
    assert e_kalman[healthy].min() > 10 * e_uio[healthy].max()
    # sensor fault: flagged at its first sample (delay 0), |r| about 0.49 there and 0.96 at the end
    assert norm[t == 10.0][0] > 0.4 and norm[t < 10.0][-1] < 1e-3
    assert norm[(t >= 10.0) & (t < 20.0)].min() > 0.4
    # it ends at 20 s: the residual decays with F, below 1e-3 again before 27 s
    assert norm[(t >= 27.0) & (t < 30.0)].max() < 1e-3
    # actuator fault: |r| crosses 0.05 within 0.5 s and settles at −C F⁻¹ T B f_a (eq. (12))
    crossing = t[(t >= 30.0) & (norm > 0.05)][0] - 30.0
    assert 0.0 < crossing < 0.5
    e = log.estimators["uio"]
    estimator = estimators.create(e.kind, LinearModel.from_dict(e.model), e.params, log.sample_time)
    d = estimator.design
    expected = -C @ np.linalg.solve(d.F, d.T @ B @ np.array([2.0, 0.0]))
    np.testing.assert_allclose(r[-1], expected, atol=1e-3)
