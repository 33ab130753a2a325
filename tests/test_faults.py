"""Every fault model: what it adds, when, and with which statistics."""

from __future__ import annotations

import math

import numpy as np
import pytest

import faults as fm


def injector(*sensor_faults, noise=(), actuator=(), seed=0):
    return fm.FaultInjector(list(noise), list(sensor_faults), list(actuator), seed)


Y = np.array([1.0, 2.0, -3.0])


def test_waveforms():
    assert fm.Constant(2.5)(7.0) == 2.5
    assert fm.Sine(2.0, 0.25, offset=1.0)(1.0) == pytest.approx(3.0)  # sin(π/2)
    assert fm.Sine(2.0, 0.25, phase=math.pi / 2)(0.0) == pytest.approx(2.0)
    assert fm.Square(1.0, 1.0, duty=0.25)(0.1) == 1.0 and fm.Square(1.0, 1.0, duty=0.25)(0.3) == -1.0
    assert fm.Ramp(0.5, offset=1.0)(4.0) == 3.0
    assert fm.Exponential(rate=0.03)(10.0) == pytest.approx(math.exp(-0.3))  # δ1 of Cristofaro & Johansen
    assert fm.Exponential(rate=1.0, initial=2.0, final=1.0)(0.0) == 2.0
    assert fm.Sum((fm.Constant(1.0), fm.Ramp(1.0)))(2.0) == 3.0


def test_constant_bias_only_inside_its_window():
    inj = injector(fm.Bias(channels=(0, 2), start=5.0, end=8.0, label="b", value=(1.0, 0.5)))
    before, during, after = inj.sensors(Y, 4.99), inj.sensors(Y, 5.0), inj.sensors(Y, 8.0)
    np.testing.assert_array_equal(before.measured, Y)
    np.testing.assert_array_equal(during.measured, Y + [1.0, 0.0, 0.5])
    np.testing.assert_array_equal(during.fault, [1.0, 0.0, 0.5])
    assert during.active == ("b",) and before.active == () and after.active == ()
    np.testing.assert_array_equal(after.measured, Y)


def test_bias_of_constant_direction_and_varying_amplitude():
    """φ_k = g_k φ̄ (TAC 2024, eq. (35)) with g_k = 1 + 0.1 sin(100 τ k), τ = 0.01."""
    tau, direction = 0.01, np.array([1.0, -1.5, 0.5])
    g = fm.Sine(amplitude=0.1, frequency=100 / (2 * math.pi), offset=1.0)  # sin(100 τ k) = sin(100 t)
    inj = injector(fm.Bias(channels=(0, 1, 2), value=tuple(direction), amplitude=g))
    for k in range(50):
        out = inj.sensors(np.zeros(3), k * tau)
        np.testing.assert_allclose(out.fault, (1 + 0.1 * math.sin(100 * tau * k)) * direction, atol=1e-14)


def test_drift_grows_linearly_from_onset():
    inj = injector(fm.Drift(channels=(1,), start=2.0, rate=(0.1,)))
    np.testing.assert_allclose(inj.sensors(Y, 7.0).fault, [0.0, 0.5, 0.0])
    np.testing.assert_allclose(inj.sensors(Y, 1.0).fault, [0.0, 0.0, 0.0])


def test_gain_fault_scales_the_reading():
    """y_i ← γ_i y_i (IJC 2018, eq. (2)–(4)), with a time-varying γ."""
    inj = injector(fm.Gain(channels=(0, 2), start=1.0, gain=(fm.Constant(0.6), fm.Ramp(-0.1, offset=1.0))))
    out = inj.sensors(Y, 3.0)
    np.testing.assert_allclose(out.measured, [0.6, 2.0, -3.0 * 0.8])


def test_gaussian_noise_statistics_and_reproducibility():
    std = (0.5, 2.0)
    inj = injector(noise=[fm.GaussianNoise(channels=(0, 1), std=std)], seed=4)
    samples = np.array([inj.sensors(np.zeros(3), k * 0.01).noise for k in range(40000)])
    # sample std within 2% (its standard error is std/sqrt(2N) = 0.35%), mean within 4 standard errors
    np.testing.assert_allclose(samples[:, :2].std(axis=0), std, rtol=0.02)
    assert np.all(np.abs(samples[:, :2].mean(axis=0)) < 4 * np.array(std) / np.sqrt(40000))
    assert np.all(samples[:, 2] == 0)
    again = injector(noise=[fm.GaussianNoise(channels=(0, 1), std=std)], seed=4)
    np.testing.assert_array_equal(again.sensors(np.zeros(3), 0.0).noise, samples[0])
    other = injector(noise=[fm.GaussianNoise(channels=(0, 1), std=std)], seed=5)
    assert not np.array_equal(other.sensors(np.zeros(3), 0.0).noise, samples[0])


def test_noise_is_not_a_fault_and_streams_are_independent():
    """Adding a random fault does not change the noise sequence (each model has its own stream)."""
    noise = lambda: [fm.GaussianNoise(channels=(0, 1, 2), std=1.0)]  # noqa: E731
    alone = injector(noise=noise(), seed=1)
    with_fault = injector(fm.Dropout(channels=(0,), probability=0.5), noise=noise(), seed=1)
    for k in range(100):
        a, b = alone.sensors(Y, k * 0.01), with_fault.sensors(Y, k * 0.01)
        np.testing.assert_array_equal(a.noise, b.noise)
    assert alone.first_onset is None and with_fault.first_onset == 0.0


def test_uniform_noise_is_bounded_with_the_right_variance():
    inj = injector(noise=[fm.UniformNoise(channels=(0,), bound=(0.3,))], seed=2)
    samples = np.array([inj.sensors(np.zeros(1), 0.0).noise[0] for _ in range(40000)])
    assert samples.min() >= -0.3 and samples.max() <= 0.3
    assert samples.var() == pytest.approx(0.3**2 / 3, rel=0.03)


def test_stuck_at_holds_the_onset_reading_or_a_given_value():
    held = injector(fm.StuckAt(channels=(0,), start=1.0))
    assert held.sensors(np.array([5.0]), 0.5).measured[0] == 5.0
    assert held.sensors(np.array([6.0]), 1.0).measured[0] == 6.0
    assert held.sensors(np.array([9.0]), 2.0).measured[0] == 6.0
    fixed = injector(fm.StuckAt(channels=(0,), value=(0.25,)))
    assert fixed.sensors(np.array([9.0]), 0.0).measured[0] == 0.25


def test_dropout_drops_frames_at_the_given_rate():
    inj = injector(fm.Dropout(channels=(0, 1), probability=0.2), seed=3)
    outcomes = [inj.sensors(Y, 0.0) for _ in range(20000)]
    dropped = np.array([~o.sent for o in outcomes])
    assert all(np.array_equal(o.measured, Y) for o in outcomes)  # the readings themselves are untouched
    assert dropped[:, 2].sum() == 0
    # binomial: standard error sqrt(0.2*0.8/20000) = 0.0028
    np.testing.assert_allclose(dropped[:, :2].mean(axis=0), 0.2, atol=0.012)


def test_outliers_are_spikes_of_the_given_magnitude():
    inj = injector(fm.Outliers(channels=(0,), probability=0.1, magnitude=(4.0,)), seed=3)
    deviations = np.array([inj.sensors(np.zeros(1), 0.0).fault[0] for _ in range(20000)])
    assert set(np.unique(deviations)) <= {-4.0, 0.0, 4.0}
    assert np.mean(deviations != 0) == pytest.approx(0.1, abs=0.01)
    assert np.mean(deviations[deviations != 0] > 0) == pytest.approx(0.5, abs=0.05)


def test_actuator_loss_of_effectiveness():
    """u_eff = δ(t) u with δ1 = e^(−0.03 t) (Cristofaro & Johansen, Sec. 4) on a group of inputs."""
    inj = injector(
        actuator=[fm.ActuatorEffectiveness(channels=(0, 1), start=0.0, effectiveness=(fm.Exponential(0.03),) * 2)]
    )
    u_eff, delta = inj.actuators(np.array([2.0, 4.0, 1.0]), 10.0)
    np.testing.assert_allclose(delta, [math.exp(-0.3), math.exp(-0.3), 1.0])
    np.testing.assert_allclose(u_eff, [2 * math.exp(-0.3), 4 * math.exp(-0.3), 1.0])
    assert inj.first_onset == 0.0


def test_measured_is_true_plus_noise_plus_fault():
    inj = injector(
        fm.Bias(channels=(0, 1, 2), value=(1.0, -1.5, 0.5)),
        fm.Gain(channels=(1,), gain=(fm.Constant(0.5),)),
        noise=[fm.GaussianNoise(channels=(0, 1, 2), std=0.1)],
        seed=7,
    )
    out = inj.sensors(Y, 1.0)
    np.testing.assert_allclose(out.measured, Y + out.noise + out.fault, atol=1e-15)
    np.testing.assert_allclose(out.measured[1], 0.5 * (Y[1] + out.noise[1] - 1.5))


def test_vector_length_is_checked():
    with pytest.raises(ValueError, match="expected 2 values"):
        fm.Bias(channels=(0, 1), value=(1.0, 2.0, 3.0))


def test_random_streams_are_keyed_by_label_not_position():
    """Removing or reordering other faults does not change a fault's random sequence."""

    def draws(faults):
        inj = injector(*faults, seed=9)
        return np.array([inj.sensors(np.zeros(2), k * 0.01).fault for k in range(50)])

    outliers = lambda: fm.Outliers(channels=(1,), probability=0.5, magnitude=(1.0,), label="spikes")  # noqa: E731
    alone = draws([outliers()])
    behind_another = draws([fm.Outliers(channels=(0,), probability=0.5, magnitude=(1.0,), label="other"), outliers()])
    np.testing.assert_array_equal(alone[:, 1], behind_another[:, 1])


def test_duplicate_labels_are_refused():
    with pytest.raises(ValueError, match="fault labels must be unique"):
        injector(fm.Bias(channels=(0,), value=(1.0,), label="a"), fm.Drift(channels=(0,), rate=(1.0,), label="a"))


def test_actuator_offset_is_additive_inside_its_window():
    """u_eff = u + g(t − start) · value (the f_a of the course notes' eq. (11)), on the chosen inputs only."""
    inj = injector(
        actuator=[
            fm.ActuatorOffset(channels=(1,), start=2.0, end=5.0, value=(0.5,), amplitude=fm.Ramp(1.0, offset=1.0))
        ]
    )
    u = np.array([1.0, -2.0])
    u_eff, delta = inj.actuators(u, 3.0)
    np.testing.assert_allclose(u_eff, [1.0, -2.0 + 0.5 * 2.0])
    np.testing.assert_array_equal(delta, [1.0, 1.0])
    np.testing.assert_array_equal(inj.actuators(u, 1.99)[0], u)
    np.testing.assert_array_equal(inj.actuators(u, 5.0)[0], u)
    assert inj.first_onset == 2.0 and [f.label for f in inj.faults] == ["actuator_offset0"]


def test_actuator_offset_composes_with_loss_of_effectiveness():
    """u_eff = (∏ δ) ∘ u + Σ f_a, whatever the order of the faults."""

    def loss():
        return fm.ActuatorEffectiveness(
            channels=(0, 1), label="loss", effectiveness=(fm.Constant(0.5), fm.Constant(0.25))
        )

    def offset():
        return fm.ActuatorOffset(channels=(0,), label="offset", value=(2.0,))

    def more():
        return fm.ActuatorOffset(channels=(0, 1), label="more", value=(1.0, -1.0))

    u = np.array([4.0, 8.0])
    for order in ((loss(), offset(), more()), (more(), offset(), loss())):
        u_eff, delta = injector(actuator=list(order)).actuators(u, 1.0)
        np.testing.assert_allclose(u_eff, [0.5 * 4.0 + 2.0 + 1.0, 0.25 * 8.0 - 1.0])
        np.testing.assert_allclose(delta, [0.5, 0.25])
    with pytest.raises(ValueError, match="actuator offset value: expected 2 values"):
        fm.ActuatorOffset(channels=(0, 1), value=(1.0, 2.0, 3.0))


SCENARIO = """
name = "offset"
duration = 1.0
sample_time = 0.1

[plant]
model = "state-space"

[plant.state_space]
A = [[-1.0, 0.0], [0.0, -2.0]]
B = [[1.0, 0.0], [0.0, 1.0]]
C = [[1.0, 0.0]]
inputs = ["ua", "ub"]
"""


def test_actuator_offset_in_a_scenario():
    from cosim.scenario import build_faults, parse

    s = parse(
        SCENARIO
        + '[[faults]]\nname = "stuck_on"\nkind = "actuator_offset"\nactuators = ["ub"]\nvalue = 0.3\nstart = 0.5\n'
        'amplitude = { kind = "constant", value = 2.0 }\n'
    )
    inj = build_faults(s)
    assert [(f.label, f.kind, f.channels) for f in inj.faults] == [("stuck_on", "actuator_offset", (1,))]
    np.testing.assert_allclose(inj.actuators(np.array([1.0, 1.0]), 0.5)[0], [1.0, 1.6])
    every = build_faults(parse(SCENARIO + '[[faults]]\nkind = "actuator_offset"\nvalue = [0.1, 0.2]\n'))
    np.testing.assert_allclose(every.actuators(np.zeros(2), 0.0)[0], [0.1, 0.2])


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (
            'actuators = ["uc"]\nvalue = 1.0\n',
            r"faults\[0\]\.actuators: state-space has no actuator 'uc'; it has: ua, ub",
        ),
        ("value = [1.0, 2.0, 3.0]\n", r"faults\[0\]\.value: has 3 values for 2 channels"),
        ('actuators = ["ua"]\n', r"faults\[0\]\.value: required but missing"),
        ('value = 1.0\nsensors = ["y1"]\n', r"faults\[0\]: unknown key 'sensors'"),
    ],
)
def test_actuator_offset_errors_name_the_field(extra, message):
    from cosim.errors import ScenarioError
    from cosim.scenario import parse

    with pytest.raises(ScenarioError, match=message):
        parse(SCENARIO + '[[faults]]\nkind = "actuator_offset"\n' + extra)
