"""The batched steps of the IJC 2018 reconciliators (``estimators.reconciliation_batch``) against their
single steps, bit for bit, on runs that take other branches at the same tick: gain faults of other
sensors at other onsets (so that at one tick some runs' gain test accepts γ̂ while others reject it,
identify new gains, replay their window or coast), readings missing in some runs (the model window's
own projection, the UIO's prediction), and a run whose arithmetic fails."""

from __future__ import annotations

import numpy as np
import pytest

import estimators
import estimators.reconciliation_batch as reconciliation_batch
from estimators.batched import batch_of, check_batched
from estimators.gain_identification import split_systems, standard_errors, window_equations, window_tests
from estimators.lmi import box_coordinates, box_coordinates_runs
from estimators.model_window import model_window, window_gains, window_gains_runs
from estimators.reconciliation_batch import UioReconciliationBatch
from tests.paper_three_tank import HIGH, HZ, LOW, A, B, C, E, paper_lft_design, paper_model

NOISE = 0.01
STEPS = 150
WINDOW = {"window": 24, "min_window": 8}  # shorter than the scenario's 50: the same branches, in less time


def tank_runs(onsets: list[tuple[int, int, float]], steps: int = STEPS, seed: int = 0):
    """Readings and inputs of runs of the paper's linear plant (58) under the scenario's square-wave
    inflows (each run's phase its own), y = Δ(γ)(C x + n) + F b with n ~ N(0, 0.01²) and a 2 cm bias
    from tick 12: run r's sensor ``onsets[r][0]`` drops to gain ``onsets[r][2]`` at tick
    ``onsets[r][1]``. Returns y (steps, runs, 4) and u (steps, runs, 2)."""
    rng = np.random.default_rng(seed)
    runs = len(onsets)
    y, u = np.empty((steps, runs, 4)), np.empty((steps, runs, 2))
    for r, (sensor, onset, gain) in enumerate(onsets):
        x, phase = np.zeros(3), 0.1 * r
        for k in range(steps):
            u[k, r] = 8.0 * np.sign(np.sin(2 * np.pi * np.array([k / 150 + phase, k / 97 + 0.16])))
            gamma = np.where((np.arange(4) == sensor) & (k >= onset), gain, 1.0)
            y[k, r] = gamma * (C @ x + NOISE * rng.standard_normal(4)) + (2.0 if k >= 12 else 0.0)
            x = A @ x + B @ u[k, r] + E[:, 0] * 0.02 * np.sin(2 * np.pi * k / 90)
    return y, u


#: Run r: (sensor, onset, gain). Runs 0 and 3 change at the same tick (their windows identify
#: together), run 1 later, run 2 never, run 4 a small change.
ONSETS = [(0, 50, 0.6), (1, 95, 0.75), (2, 10_000, 1.0), (3, 50, 0.5), (0, 65, 0.9)]


def readings() -> tuple[np.ndarray, np.ndarray]:
    y, u = tank_runs(ONSETS)
    y[30:34, 2, 1] = np.nan  # run 2 loses sensor 2 for a while (inside its window for 24 ticks more)
    y[62, 0, :] = np.nan  # run 0 loses every reading for a tick, while identifying
    y[120, 4, 3] = np.nan
    # Run 2 (no fault): a burst of noise on two sensors for 34 ticks, which no constant gains explain
    # (its UIO coasts, then goes on), and an outlier once its window holds none of the burst.
    y[36:70, 2, 2:] += np.random.default_rng(5).normal(0.0, 0.5, (34, 2))
    y[118, 2, 2] += 0.3
    return y, u


@pytest.fixture(scope="module")
def lft():
    return paper_lft_design()


def make(lft, kind: str, **params):
    """A reconciliator of the paper's model; LPV with the LFT gain at every vertex (any certified
    gain will do: its G(ρ̂)⁻¹ Y(ρ̂) is still formed and solved every time γ̂ moves)."""
    base = {"Hz": HZ, "design_gamma_min": 0.5} | WINDOW | params
    if kind == "lft-uio-sr":
        base["L"] = lft.L.tolist()
    elif kind == "lpv-uio-sr":
        G = np.eye(4) * np.linspace(1.0, 2.0, 16)[:, None, None]  # other G_i: G(ρ̂) depends on ρ̂
        base |= {"G": G.reshape(64, 4).tolist(), "Y": (G @ lft.L).reshape(64, 4).tolist()}
    return lambda: estimators.create(kind, paper_model(), base)


def alone(factory, y, u) -> dict[str, np.ndarray]:
    """Each run stepped alone: its diagnostics, (ticks, runs) per name."""
    instances = [factory() for _ in range(y.shape[1])]
    rows = [[e.step(y[k, r], u[k, r]).diagnostics for r, e in enumerate(instances)] for k in range(len(y))]
    return {name: np.array([[d[name] for d in row] for row in rows]) for name in rows[0][0]}


GAMMAS = [f"gamma_y{i}" for i in (1, 2, 3, 4)]


@pytest.mark.parametrize("kind", ["lft-uio-sr", "lpv-uio-sr"])
@pytest.mark.parametrize("estimator", ["paper", "model"])
def test_the_batched_step_with_53_or_the_model_window_equals_the_single_step(lft, kind, estimator):
    y, u = readings()
    factory = make(lft, kind, gain_estimator=estimator)
    check_batched(factory, y, u)
    seen = alone(factory, y, u)
    gammas = np.stack([seen[name] for name in GAMMAS], axis=2)
    moved = (gammas[1:] != gammas[:-1]).any(axis=2)
    if estimator == "model":  # γ̂ is kept in some runs at ticks where it moves in others
        assert (moved.any(axis=1) & ~moved.all(axis=1)).any()
    else:  # (53) moves it every tick in every run, from a different window in each
        assert moved[WINDOW["window"] :].all()


def test_the_batched_gain_test_equals_the_single_step_while_runs_accept_identify_and_coast(lft):
    y, u = readings()
    for kind in ("lft-uio-sr", "lpv-uio-sr"):
        factory = make(lft, kind, gain_estimator="test", noise_std=NOISE)
        check_batched(factory, y, u)
    seen = alone(factory, y, u)
    gammas = np.stack([seen[name] for name in GAMMAS], axis=2)
    changed = (gammas[1:] != gammas[:-1]).any(axis=2)  # (ticks − 1, runs): a run identified new gains
    assert changed[:, [0, 1, 3, 4]].any(axis=0).all() and not changed[:, 2].any()
    assert not changed.all(axis=1).any()  # never every run at once
    rejected = seen["fit"] > 1.0  # the statistic over its threshold: the window rejects γ̂
    assert (rejected.any(axis=1) & ~rejected.all(axis=1)).sum() > 20  # runs accept while others reject
    assert np.abs(gammas[-1, 0] - [0.6, 1, 1, 1]).max() < 0.02 and np.abs(gammas[-1, 3] - [1, 1, 1, 0.5]).max() < 0.02


def test_a_batch_whose_shared_gain_search_raises_has_each_run_search_alone(lft, monkeypatch):
    """Should the gain search of all searching runs at once raise (one run's arithmetic), each run
    searches its own window, as alone: the batch is still each run's single step."""

    calls = []

    def raising(*args, **kwargs):
        calls.append(len(args[0]))
        raise FloatingPointError("one run's search")

    monkeypatch.setattr(reconciliation_batch, "searched_windows", raising)
    y, u = readings()
    check_batched(make(lft, "lft-uio-sr", gain_estimator="test", noise_std=NOISE), y, u)
    assert len(calls) > 5 and max(calls) > 1  # several runs searched at once, more than once


@pytest.mark.parametrize("stack", ["solved", "raises"])
def test_no_reconciliation_batched_equals_its_single_step(stack, monkeypatch):
    """The runs with every reading solved together, the others alone; and every run alone where the
    stacked call raises (LAPACK's SVD not converging), as the batch then finds which run it was."""
    if stack == "raises":

        def raising(*args: object) -> None:
            raise np.linalg.LinAlgError("SVD did not converge in Linear Least Squares")

        monkeypatch.setattr(reconciliation_batch, "lstsq_runs", raising)
    y, u = readings()
    y[40, 1, :] = np.nan  # every reading missing: the operating point
    check_batched(lambda: estimators.create("no-reconciliation", paper_model(), {"Hz": HZ}), y, u)


def test_a_run_whose_arithmetic_fails_is_out_at_the_tick_it_fails_alone_and_the_others_go_on(lft):
    y, u = readings()
    y[40, 1, 2] = np.inf  # run 1's window cannot be solved once it holds that reading
    factory = make(lft, "lft-uio-sr", gain_estimator="model")
    batch = batch_of([factory() for _ in range(y.shape[1])])
    assert isinstance(batch, UioReconciliationBatch)
    instances = [factory() for _ in range(y.shape[1])]
    raised: dict[int, tuple[int, str]] = {}
    for k in range(60):
        together = batch.step(y[k], u[k])
        for r, instance in enumerate(instances):
            if r in raised:
                assert np.isnan(together.x[r]).all()
                continue
            try:
                single = instance.step(y[k, r], u[k, r])
            except Exception as error:  # noqa: BLE001
                raised[r] = (k, f"{type(error).__name__}: {error}")
                assert together.failed.get(r) == raised[r][1] and np.isnan(together.x[r]).all()
                continue
            assert r not in together.failed and np.array_equal(together.x[r], single.x)
            assert all(together.diagnostics[n][r] == v for n, v in single.diagnostics.items())
    assert list(raised) == [1] and raised[1][0] == 40


# -- the K-run forms against the one-run forms they replace ----------------------------------------


def test_the_k_run_box_coordinates_are_the_one_run_ones_on_the_box_and_off_it():
    rng = np.random.default_rng(2)
    gammas = rng.uniform(0.3, 1.2, (500, 4))
    gammas[::7] = LOW
    gammas[1::7, 2] = -0.0
    found = box_coordinates_runs(gammas, LOW, HIGH)
    assert all(np.array_equal(found[k], box_coordinates(g, LOW, HIGH)) for k, g in enumerate(gammas))


def test_the_k_run_model_window_and_gain_test_are_the_one_run_ones():
    """``window_gains_runs`` and ``window_tests`` on windows of other runs, against ``window_gains``
    and the test ``decide_gains`` makes first (T(1/γ̂) over its threshold, the standard errors)."""
    from estimators.gain_hypotheses import chi2_quantile as _chi2_quantile
    from estimators.gain_identification import chi2_statistic, gain_standard_errors, window_system

    y, u = tank_runs(ONSETS + ONSETS, steps=50, seed=3)
    ys, us = np.swapaxes(y, 0, 1), np.concatenate((np.swapaxes(u, 0, 1), np.ones((10, 50, 1))), axis=2)
    base = {"Hz": HZ, "design_gamma_min": 0.5, "L": np.zeros((4, 4)).tolist()}
    window = model_window(A, estimators.create("lft-uio-sr", paper_model(), base).aug.B, E, C, 50)
    gammas, sv, fit = window_gains_runs(window, ys, us, LOW, HIGH)
    for r in range(10):
        one = window_gains(window, ys[r], us[r], LOW, HIGH)
        assert np.array_equal(one[0], gammas[r]) and np.array_equal(one[1], sv[r]) and one[2] == fit[r]
    tested = base | {"gain_estimator": "test", "noise_std": NOISE}
    test = estimators.create("lft-uio-sr", paper_model(), tested).gain_test
    previous = np.random.default_rng(1).uniform(0.5, 1.0, (10, 4))
    statistic, excitation = window_tests(test, ys, us, previous, 1e-6, 0.05)
    for r in range(10):
        full = window_system(test, ys[r], us[r])
        assert statistic[r] == chi2_statistic(full, 1.0 / previous[r]) / _chi2_quantile(1e-6, full.dof)
        assert excitation[r] == 0.05 / float(np.max(gain_standard_errors(full)))
        assert np.array_equal(standard_errors(full.factor[None])[0], gain_standard_errors(full))
    # every split of every run's window at once, against each split's own system
    befores = 1.0 / previous
    splits = split_systems(test, [window_equations(test, ys[r], us[r]) for r in range(10)], befores)
    for r in range(10):
        for L, found in zip(range(test.min_window, 50), splits[r], strict=True):
            one = window_system(test, ys[r], us[r], change=50 - L, before=befores[r])
            assert all(np.array_equal(a, b) for a, b in zip(found, one, strict=True)), (r, L)


def test_the_k_run_uio_step_is_each_runs_own_with_runs_starting_coasting_or_missing_readings(lft):
    """``uio_steps`` against ``_observe`` of each run, with some runs at their first step (from x̂₀),
    some coasting, some missing a reading, the others stepping from their previous estimate."""
    from estimators.reconciliation_batch import uio_runs
    from estimators.reconciliation_runs import uio_steps

    y, u = tank_runs(ONSETS + ONSETS, steps=3, seed=4)
    u_bar = np.concatenate((u, np.ones((3, 10, 1))), axis=2)
    runs = [make(lft, "lpv-uio-sr", x0=(1.0, -2.0, 0.5))() for _ in range(10)]  # x̂₀ ≠ 0: Ā x̂₀ ≠ x̂₀
    gammas = np.random.default_rng(6).uniform(0.5, 1.0, (10, 4))
    for r, run in enumerate(runs):
        if r % 3:  # steps from an estimate of its own; every third run starts at this tick
            run._observe(y[0, r], u_bar[0, r], gammas[r])
    fresh = np.array([r % 3 == 0 for r in range(10)])
    coast = np.array([r % 4 == 1 for r in range(10)])
    readings = y[1].copy()
    readings[[2, 5], 1] = np.nan
    start = (runs[0].x_bar0, np.zeros(4), np.zeros(3))  # a fresh run's: not read
    previous = tuple(
        np.stack(rows) for rows in zip(*(start if f else (e.x_hat, *e.previous) for e, f in zip(runs, fresh)))
    )
    first = runs[0]
    x_hat, used = uio_steps(
        uio_runs(first, gammas), first.Abar, first.Bbar, first.x_bar0, previous, fresh, readings, coast
    )
    for r, run in enumerate(runs):
        sample = run._observe(readings[r], u_bar[1, r], gammas[r], bool(coast[r]))
        assert np.array_equal(x_hat[r], run.x_hat) and np.array_equal(used[r], sample.y), r


def test_the_k_run_pseudoinverse_is_the_one_run_one_on_regular_and_singular_matrices():
    from estimators.lmi import pseudo_inverse, pseudo_inverses

    rng = np.random.default_rng(7)
    for trial in range(400):
        k, n = (int(v) for v in rng.integers(1, 6, 2))
        M = rng.standard_normal((int(rng.integers(1, 7)), k, n)) * 10.0 ** rng.uniform(-3, 3, (1, 1, 1))
        if trial % 5 == 0:
            M[0, :, 0] = 0.0  # a singular value at 0: every run by the one-run form
        found = pseudo_inverses(M)
        assert all(np.array_equal(found[r], pseudo_inverse(M[r])) for r in range(len(M))), trial
