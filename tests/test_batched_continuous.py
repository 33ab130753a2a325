"""The continuous-time adaptive observer of CDC 2016 (``adaptive-ct``) batched: K runs integrated
together, each with its own step sizes, give run for run exactly what each instance's own step gives
(``estimators.batched.check_batched``), through fault onsets that make their steps diverge, missing
and infinite readings, and a run whose integration fails."""

from __future__ import annotations

import numpy as np
import pytest

import estimators
import estimators.continuous as continuous
import estimators.rosenbrock as rosenbrock
from cosim import api
from cosim.campaign.batch import run_batch
from cosim.campaign.results import rows_of
from cosim.scenario import apply
from estimators import LinearModel
from estimators.batched import StepEach, batch_of, check_batched
from estimators.continuous_ode import ObserverODE, ObserverODERuns
from estimators.design import zoh_discretize
from tests.test_adaptive import L1, L2, Y_CDC, cdc_model

BIAS = np.array([3.0, 0.5, -1.0])  # CDC 2016 Example 1


def cdc_runs(runs: int, ticks: int, onsets: list[int], scales: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """Readings (ticks, runs, 3) of Example 1's plant, each run with its own noise, a bias of its own
    size from its own tick, and a sinusoidal input (ticks, runs, 1)."""
    model = cdc_model()
    Ad, Bd = zoh_discretize(model.A, model.B, 0.02)
    ys, us = np.empty((ticks, runs, 3)), np.empty((ticks, runs, 1))
    for r in range(runs):
        rng = np.random.default_rng(r)
        x = np.array([1.0, -1.0, 0.5])
        for k in range(ticks):
            us[k, r] = np.sin(0.05 * k + r)
            ys[k, r] = model.C @ x + (scales[r] * BIAS if k >= onsets[r] else 0.0) + rng.uniform(-0.01, 0.01, 3)
            x = Ad @ x + Bd @ us[k, r]
    return ys, us


@pytest.fixture
def attempts(monkeypatch):
    """How many runs made each attempt of the batched integration (``_rosenbrock_steps``' rows)."""
    seen: list[int] = []
    steps = rosenbrock._rosenbrock_steps

    def counted(ode, rows, *args):
        seen.append(len(rows))
        return steps(ode, rows, *args)

    monkeypatch.setattr(rosenbrock, "_rosenbrock_steps", counted)
    return seen


@pytest.mark.parametrize(("gain", "kappa"), [(L2, 10.0), (L1, 1.0), (L1, 0.0)])
def test_batched_runs_are_each_run_alone_through_faults_of_their_own(gain, kappa, attempts):
    """Eight runs of Example 1, the bias of each its own size from its own tick: their step sizes
    diverge at each onset (the stiff adaptation after it rejects steps), so runs sit out attempts
    the others make; a run with a missing reading integrates open loop; every value of every run is
    its value alone."""
    runs = 8
    ys, us = cdc_runs(runs, 260, [30, 60, 61, 90, 120, 150, 400, 45], [1.0, 2.0, 0.5, 1.0, 3.0, 0.2, 1.0, -1.0])
    ys[1, 6, 0] = ys[31, 0, 1] = ys[62:65, 1] = ys[92, 3, 0] = ys[100, 5, 2] = np.nan  # in transients, or not
    params = {"gain": gain.tolist(), "Y": Y_CDC.tolist(), "kappa": kappa}
    check_batched(lambda: estimators.create("adaptive-ct", cdc_model(), params, 0.02), ys, us)
    if kappa > 0:
        assert min(attempts) < runs - 1 and max(attempts) == runs  # runs sat out others' attempts


def test_each_runs_state_in_the_batch_is_its_instances_alone():
    """The state the batch keeps for each run, x̂, Γ, the step to try next and the error scale (the
    largest |w_i| so far), after every tick equals that of the run's instance stepped alone: also
    after a missing reading, which the run's own instance steps."""
    runs = 6
    ys, us = cdc_runs(runs, 60, [5, 10, 15, 20, 25, 30], [1.0, 2.0, 0.5, 1.0, 3.0, 0.2])
    ys[1, 0, 0] = ys[6, 1, 1] = ys[16:18, 2] = np.nan
    us[6, 1] = 50.0  # which drives x̂ to a size it never had, open loop
    params = {"gain": L2.tolist(), "Y": Y_CDC.tolist(), "kappa": 10.0}
    alone = [estimators.create("adaptive-ct", cdc_model(), params, 0.02) for _ in range(runs)]
    batch = batch_of([estimators.create("adaptive-ct", cdc_model(), params, 0.02) for _ in range(runs)])
    assert isinstance(batch, continuous._ContinuousBatch)
    for k in range(len(ys)):
        batch.step(ys[k], us[k])
        for r, e in enumerate(alone):
            e.step(ys[k, r], us[k, r])
            state = (batch.x[r], batch.gamma[r], batch.h[r], batch.size[r])
            for batched, single in zip(state, (e.x_hat, e.gamma, e.h, e.size)):
                np.testing.assert_array_equal(batched, single, err_msg=f"tick {k}, run {r}")


def random_model(rng: np.random.Generator, n: int, p: int, q: int) -> LinearModel:
    """A stable n-state model whose p outputs have rank q: C = Y H with random Y and H."""
    A = rng.normal(size=(n, n))
    A -= (np.max(np.linalg.eigvals(A).real) + 1.0) * np.eye(n)
    C = rng.normal(size=(p, q)) @ rng.normal(size=(q, n))
    states, outputs = tuple(f"x{i}" for i in range(n)), tuple(f"y{i}" for i in range(p))
    return LinearModel(A, rng.normal(size=(n, 2)), C, np.zeros((p, 2)), None, states, ("u1", "u2"), outputs)


@pytest.mark.parametrize(("n", "p", "q"), [(2, 2, 1), (3, 3, 2), (4, 4, 3), (4, 5, 3)])
def test_batched_runs_are_each_run_alone_for_other_output_ranks(n, p, q):
    """Random plants with q = rk C from 1 to 3 (R⁻¹ in closed form for q ≤ 2, NumPy's stacked inv
    above), random readings with a bias that switches on in some runs, two inputs."""
    rng = np.random.default_rng(10 * n + q)
    model = random_model(rng, n, p, q)
    runs, ticks = 7, 80
    ys = rng.normal(size=(ticks, runs, p)) + np.where(np.arange(ticks)[:, None, None] >= 20, rng.normal(size=p), 0.0)
    ys[:, ::2] = rng.normal(size=(ticks, 1, p)) * 0.1  # runs 0, 2, 4, 6: small readings, no bias
    us = rng.normal(size=(ticks, runs, 2))
    poles = [-2.0 - i for i in range(n)]
    for kappa in (0.5, 20.0):
        params = {"poles": poles, "kappa": kappa}
        check_batched(lambda params=params: estimators.create("adaptive-ct", model, params, 0.05), ys, us)


@pytest.mark.parametrize("q", [1, 2, 3])
def test_the_k_run_field_and_jacobian_are_each_runs(q):
    """``ObserverODERuns`` against ``ObserverODE`` row by row on random states, readings and inputs,
    rows in any subset, runs of three designs (their own gain L and learning rates, as estimators
    of one scenario that step together): f, ∂f/∂w and det R bit for bit, NaN where R is singular
    (q ≤ 2); with q = 3 a run whose R is singular raises alone and is in ``raised`` with what it raised."""
    rng = np.random.default_rng(q)
    n, p, runs = 4, q + 2, 9
    A, B = rng.normal(size=(n, n)), rng.normal(size=(n, 2))
    Y, H = rng.normal(size=(p, q)), rng.normal(size=(q, n))
    designs = [
        ObserverODE(A, B, H, rng.normal(size=(n, q)), Y, kp, kg) for kp, kg in [(3.0, 2.0), (0.0, 0.0), (10.0, 1.5)]
    ]
    together = ObserverODERuns([designs[r % 3] for r in range(runs)])
    y, u = rng.normal(size=(runs, p)) * 10.0 ** rng.integers(-3, 4, size=(runs, 1)), rng.normal(size=(runs, 2))
    w = np.concatenate([rng.normal(size=(runs, n)), rng.uniform(-1.0, 1.0, (runs, p))], axis=1)
    w[3, n:] = 0.0  # R = 0: singular
    together.hold(y, u)
    rows = np.array([0, 2, 3, 5, 6, 8])
    f, J = together.linearized(w[rows], rows)
    np.testing.assert_array_equal(together(w[rows], rows), f)
    dets = together.weight_det(w[rows, n:])
    for i, r in enumerate(rows.tolist()):
        single = designs[r % 3]
        single.hold(y[r], u[r])
        np.testing.assert_array_equal(single.Bu, together.Bu[r])
        assert single.weight_det(w[r, n:]) == dets[i] or r == 3
        if q > 2 and r == 3:
            with pytest.raises(np.linalg.LinAlgError) as error:
                single.linearized(w[r])
            assert together.raised == {3: f"LinAlgError: {error.value}"}
            assert np.isnan(f[i]).all()
            continue
        f_alone, J_alone = single.linearized(w[r])
        np.testing.assert_array_equal(f[i], f_alone)
        np.testing.assert_array_equal(J[i], J_alone)
    assert np.isnan(f[2]).all() if q <= 2 else together.raised


def test_runs_whose_integration_fails_are_out_and_the_others_go_on():
    """A reading of 1e100 (or an infinite one, taken as the largest float) makes a run's integration
    fail (its step falls below 1e-12 of the sample time): alone its step raises; batched, that run
    is in ``failed`` from that tick on with what it raised, its row NaN, and the other runs are
    still exactly themselves."""
    runs, fails = 6, {4: 25, 1: 30}
    ys, us = cdc_runs(runs, 40, [10] * runs, [1.0] * runs)
    ys[25, 4, 0], ys[30, 1, 2] = 1e100, -np.inf
    params = {"gain": L2.tolist(), "Y": Y_CDC.tolist(), "kappa": 10.0}
    alone = [estimators.create("adaptive-ct", cdc_model(), params, 0.02) for _ in range(runs)]
    batch = batch_of([estimators.create("adaptive-ct", cdc_model(), params, 0.02) for _ in range(runs)])
    assert not isinstance(batch, StepEach)
    raised: dict[int, str] = {}
    for k in range(len(ys)):
        together = batch.step(ys[k], us[k])
        for r, e in enumerate(alone):
            if k == fails.get(r):
                with pytest.raises(FloatingPointError) as error:
                    e.step(ys[k, r], us[k, r])
                raised[r] = f"FloatingPointError: {error.value}"
            if r in raised:
                assert np.isnan(together.x[r]).all()
                assert all(np.isnan(v[r]) for v in together.diagnostics.values())
                continue
            single = e.step(ys[k, r], us[k, r])
            np.testing.assert_array_equal(together.x[r], single.x)
            for name, value in single.diagnostics.items():
                assert together.diagnostics[name][r] == value, (k, r, name)
        assert together.failed == raised
    assert set(raised) == set(fails)


def test_a_run_that_fails_with_a_missing_reading_is_out_too():
    """The same failure in a run stepped by its own instance (a missing reading there, beside an infinite one)."""
    runs = 6
    ys, us = cdc_runs(runs, 12, [0] * runs, [1.0] * runs)
    ys[5, 1] = [np.inf, np.nan, 0.0]
    params = {"gain": L2.tolist(), "Y": Y_CDC.tolist(), "kappa": 10.0}
    batch = batch_of([estimators.create("adaptive-ct", cdc_model(), params, 0.02) for _ in range(runs)])
    for k in range(len(ys)):
        together = batch.step(ys[k], us[k])
    assert set(together.failed) == {1} and together.failed[1].startswith("FloatingPointError: ")
    assert np.isnan(together.x[1]).all() and np.isfinite(np.delete(together.x, 1, axis=0)).all()


def test_a_few_runs_step_one_by_one_and_the_k_run_step_is_exact_for_them_too(monkeypatch):
    """Below ``BATCH_FROM`` runs the K-run step would cost more than the runs alone: the batch steps
    each instance (``StepEach``); made to take them, it is exact for one or two runs as for many."""
    params = {"gain": L2.tolist(), "Y": Y_CDC.tolist(), "kappa": 10.0}
    make = lambda: estimators.create("adaptive-ct", cdc_model(), params, 0.02)  # noqa: E731
    assert isinstance(batch_of([make() for _ in range(continuous.BATCH_FROM - 1)]), StepEach)
    assert not isinstance(batch_of([make() for _ in range(continuous.BATCH_FROM)]), StepEach)
    monkeypatch.setattr(continuous, "BATCH_FROM", 1)
    for runs in (1, 2):
        ys, us = cdc_runs(runs, 80, [20, 40], [1.0, 2.0])
        check_batched(make, ys, us)


@pytest.mark.slow
def test_a_batch_of_example_1_gives_each_runs_metrics_row_alone(monkeypatch):
    """The CDC 2016 scenario (six adaptive-ct estimators: two gains, three learning rates), its
    fault moved to 1 s, two seeds in one batch (the six estimators' 12 instances by one K-run step,
    each on its own gain and rates: ``joint_batch_key``) against each seed run alone: the same
    metrics row, every float."""
    loaded = apply(api.load("cdc2016-ex1"), [("duration", 2.5), ("faults[0].start", 1.0)])
    seeds = [0, 1]
    integrated = []
    integrate = continuous._ContinuousBatch._integrate

    def counted(self, live, dy, du):
        integrated.append(len(live))
        return integrate(self, live, dy, du)

    monkeypatch.setattr(continuous._ContinuousBatch, "_integrate", counted)
    runs = run_batch(loaded, seeds)
    assert [run.left for run in runs] == [""] * len(seeds)
    assert len(integrated) == 125 and set(integrated) == {6 * len(seeds)}  # 125 ticks of six estimators' runs
    for seed, run in zip(seeds, runs):
        alone = rows_of(api.run(loaded, None, seed=seed, in_process=True, measure=True).metrics)
        assert rows_of(run.metrics) == alone, seed


def test_an_estimator_that_fails_in_a_joint_step_takes_its_own_run_out_under_its_own_name(monkeypatch):
    """The six estimators of two runs step as one batch of 12 (estimator after estimator): the
    fifth estimator's instance of the second run raising at tick 40 takes that run out of the batch
    naming that estimator, and the other run ends as alone."""
    loaded = apply(api.load("cdc2016-ex1"), [("duration", 1.0)])
    integrate = continuous._ContinuousBatch._integrate
    ticks = []

    def failing(self, live, dy, du):
        ticks.append(None)
        if len(ticks) == 41:
            self.failed[4 * 2 + 1] = "RuntimeError: the integration gave up"
        return integrate(self, live, dy, du)

    monkeypatch.setattr(continuous._ContinuousBatch, "_integrate", failing)
    first, second = run_batch(loaded, [0, 1])
    names = [e.name for e in loaded.scenario.estimators]
    assert second.left == f"tick 40: estimator {names[4]} raised RuntimeError: the integration gave up"
    assert first.left == "" and rows_of(first.metrics) == rows_of(
        api.run(loaded, None, seed=0, in_process=True, measure=True).metrics
    )
