"""The gain test's stacked hypothesis search (estimators/gain_hypotheses.py) against the search of
one system at a time as it was written before it was stacked (``one_system_search`` below, the
loop over hypotheses with NumPy calls on one system): every system's accepted hypotheses the same,
bit for bit (``==``, never a tolerance), on random systems and on the systems the gain test
searched on the paper's linear plant with noise while gain faults and a bias step were identified;
in stacks whose systems stop at different sizes, with different previous gains."""

from __future__ import annotations

import itertools
import math
from collections import Counter

import numpy as np
import pytest
import scipy.special

import estimators.gain_identification as gain_identification
from estimators.box_least_squares import box_least_squares
from estimators.gain_hypotheses import SystemStack, chi2_quantile, normal_inverse, stacked_hypotheses
from estimators.gain_identification import (
    WindowSystem,
    _unambiguous,
    gain_hypotheses,
    gain_test_window,
    searched_windows,
    window_system,
    window_systems,
)
from estimators.lmi import pseudo_inverse
from tests.paper_three_tank import WINDOW, A, B, C, E, linear_window
from tests.test_gain_identification import gain_test, simulate_noisy

ALPHA = 1e-6
LOWER, UPPER = np.ones(4), np.full(4, 2.0)  # β = 1/γ within γ ∈ [0.5, 1]


def one_normal_inverse(columns, events):
    gram = columns.T @ columns
    if gram.shape == (1, 1):
        g = float(gram[0, 0])
        if g == 0.0:
            return np.zeros((1, 1))
        if 1e-100 < g < 1e100:
            return np.array([[1.0 / g]])
        events["scaled 1 × 1"] += 1
    return pseudo_inverse(gram)


def one_system_search(system, alpha, lower, upper, previous, samples, events):
    """The search of one system, hypothesis by hypothesis (the code of ``gain_hypotheses`` before it
    was stacked), counting in ``events`` which of its branches it took."""
    R, c = system.factor, system.rotated
    m = R.shape[1]
    for size in range(m + 1):
        dof = system.dof - size
        threshold = chi2_quantile(alpha, dof)
        if system.rest > threshold:
            events[f"stopped by rest at size {size}"] += 1
            return []
        accepted = []
        for free in itertools.combinations(range(m), size):
            index = list(free)
            columns = R[:, index]
            covariance = one_normal_inverse(columns, events) if free else np.zeros((0, 0))
            error = math.sqrt(max(covariance.diagonal().tolist())) if free else 0.0
            low, high = lower[index].tolist(), upper[index].tolist()
            recovered = [j for j in range(m) if j not in free and previous[j] != 1.0]
            for back in itertools.product((False, True), repeat=len(recovered)):
                events["back to 1"] += any(back)
                beta = np.array(previous, dtype=float)
                beta[[j for j, b in zip(recovered, back) if b]] = 1.0
                if free:
                    beta[index] = 0.0
                    rhs = c - R @ beta
                    fitted = covariance @ (columns.T @ rhs)
                    beta[index] = fitted
                    if any(f < a or f > b for a, f, b in zip(low, fitted.tolist(), high, strict=True)):
                        residual = R @ beta - c
                        if float(residual @ residual) + system.rest > threshold:
                            events["rejected before the box"] += 1
                            continue
                        if size == 1:
                            fitted = np.clip(fitted, lower[index], upper[index])
                            events["clipped"] += 1
                        else:
                            fitted = box_least_squares(columns, rhs, lower[index], upper[index])
                            events["boxed"] += 1
                        beta[index] = fitted
                residual = R @ beta - c
                statistic = float(residual @ residual) + system.rest
                if statistic <= threshold:
                    p = float(scipy.special.chdtrc(dof, statistic))
                    accepted.append((beta, free, statistic, p, error, samples))
        if accepted:
            events[f"accepted at size {size}"] += 1
            events["ambiguous"] += len({(h[1], tuple(h[0] == 1.0)) for h in accepted}) > 1
            return accepted
    events["none accepted"] += 1
    return []


def assert_same(found, expected):
    """Hypotheses equal bit for bit, in the same order."""
    assert len(found) == len(expected)
    for h, (beta, free, statistic, p, error, samples) in zip(found, expected, strict=True):
        assert np.array_equal(h.beta, beta, equal_nan=True) and h.beta.dtype == beta.dtype
        assert (h.free, h.statistic, h.p_value, h.standard_error, h.samples) == (free, statistic, p, error, samples)
        assert all(type(v) is type(w) for v, w in zip(h[1:], (free, statistic, p, error, samples), strict=True))


def check_stack(systems, previous, samples, alpha=ALPHA, lower=LOWER, upper=UPPER):
    """The stacked search of ``systems`` against each system's own search; returns its events."""
    events: Counter[str] = Counter()
    stack = SystemStack(
        np.stack([s.factor for s in systems]),
        np.stack([s.rotated for s in systems]),
        np.array([s.rest for s in systems]),
        np.array([s.dof for s in systems]),
        np.array(previous, dtype=float),
        samples,
    )
    found = stacked_hypotheses(stack, alpha, lower, upper)
    for k, system in enumerate(systems):
        assert_same(found[k], one_system_search(system, alpha, lower, upper, previous[k], samples[k], events))
    return events


def random_system(rng, m=4):
    """A window system whose true β has some gains changed (some out of the box), with noise whose
    size sets how many gains the search must fit before it accepts, or that nothing explains."""
    scale = 10.0 ** rng.uniform(-1, 3)
    factor = np.triu(rng.standard_normal((m, m)) * scale) + np.diag(rng.uniform(0.01, 1.0, m) * scale)
    factor[:, rng.random(m) < 0.05] = 0.0  # a gain the window does not see
    beta = np.where(rng.random(m) < 0.5, 1.0, rng.uniform(0.8, 2.3, m))
    dof = int(rng.integers(6, 150))
    rotated = factor @ beta + rng.standard_normal(m) * 10.0 ** rng.uniform(-1, 1.5)
    rest = float(rng.chisquare(dof) * rng.choice([1.0, 1.0, 1.5, 3.0]))
    previous = np.where(rng.random(m) < 0.5, 1.0, beta + rng.choice([0.0, 0.3], m))
    return WindowSystem(factor, rotated, rest, dof), previous


def test_the_stacked_search_is_each_systems_own_on_random_systems():
    """2 000 random systems in stacks of 1 to 300: each one's hypotheses those of its own search,
    though the stack holds systems that accept at every size, stop on their rest, or accept nothing."""
    rng = np.random.default_rng(45)
    events: Counter[str] = Counter()
    done = 0
    while done < 2_000:
        count = int(rng.choice([1, 2, 7, 50, 300]))
        systems, previous = zip(*(random_system(rng) for _ in range(count)), strict=True)
        events += check_stack(list(systems), np.array(previous), rng.integers(10, 51, count).tolist())
        done += count
    for event in ("accepted at size 0", "accepted at size 1", "accepted at size 2", "accepted at size 3"):
        assert events[event] >= 20, events
    for event in ("stopped by rest at size 0", "none accepted", "clipped", "boxed"):
        assert events[event] >= 20, events
    assert events["stopped by rest at size 1"] >= 5 and events["stopped by rest at size 2"] >= 3
    assert events["rejected before the box"] >= 20 and events["back to 1"] >= 20 and events["ambiguous"] >= 20


def test_one_column_at_the_ends_of_the_floats_and_zero_columns_are_searched_as_alone():
    """A fitted column of norm 0, or with ‖x‖² outside the closed form's range (``normal_inverse``'s
    SVD), in a stack with ordinary systems."""
    rng = np.random.default_rng(7)
    systems, previous = [], []
    for scale in (0.0, 1e-60, 1e60, 1.0):
        system, before = random_system(rng)
        factor = system.factor.copy()
        factor[:, 1] *= scale
        systems.append(system._replace(factor=factor, rest=0.0, dof=100))
        previous.append(before)
    events = check_stack(systems, np.array(previous), [50] * len(systems))
    assert events["scaled 1 × 1"] >= 2, events


def test_the_gram_matrix_and_its_inverse_are_the_one_column_sets_own():
    """``normal_inverse`` (the stack of one) against (XᵀX)⁺ of columns laid out as ``R[:, index]``."""
    rng = np.random.default_rng(3)
    for _ in range(2_000):
        R = rng.standard_normal((4, 4)) * 10.0 ** rng.uniform(-5, 5)
        index = sorted(rng.choice(4, int(rng.integers(1, 5)), replace=False).tolist())
        columns = R[:, index]
        assert np.array_equal(normal_inverse(columns), one_normal_inverse(columns, Counter()))


@pytest.fixture(scope="module")
def searched():
    """Every search the gain test made on the paper's linear plant (58) with 0.01 cm of noise: a 2 cm
    bias from 200 s, γ1 = 0.6 from 400 s, γ2 = 0.75 from 700 s (its previous gains then not all 1);
    then γ1 = 0.6 from 300 s with constant inputs at their steady state: as (systems, previous,
    samples)."""
    found = []
    stacked = gain_identification.stacked_hypotheses

    def record(stack, alpha, lower, upper):
        assert (alpha, lower.tolist(), upper.tolist()) == (ALPHA, LOWER.tolist(), UPPER.tolist())
        systems = [WindowSystem(f, c, float(r), int(d)) for f, c, r, d in zip(*stack[:4], strict=True)]
        found.append((systems, stack.previous.copy(), list(stack.samples)))
        return stacked(stack, alpha, lower, upper)

    true = np.array([0.6, 0.75, 1.0, 1.0])
    profile = lambda k: np.where(np.array([k >= 400, k >= 700, False, False]), true, 1.0)  # noqa: E731
    steady = np.array([8.0, -8.0])
    level = np.linalg.solve(np.eye(3) - A, B @ steady)
    gain_identification.stacked_hypotheses = record
    try:
        simulate_noisy(gain_test_estimator(), 780, profile, lambda k: 2.0 * (k >= 200), 7)
        # Levels that do not move: γ1's change is an offset's step as well (ambiguous windows).
        fault = lambda k: np.where((np.arange(4) == 0) & (k >= 300), 0.6, 1.0)  # noqa: E731
        simulate_noisy(gain_test_estimator(), 360, fault, lambda k: 0.0, 1, lambda k: steady, level, v=0.0)
    finally:
        gain_identification.stacked_hypotheses = stacked
    return found


def gain_test_estimator():
    from tests.paper_three_tank import paper_lft_design

    return gain_test(paper_lft_design())


def test_the_stacked_search_is_each_systems_own_on_the_gain_tests_windows(searched):
    """Each search of the run (its whole window and its splits together), then all of them in one
    stack (systems with other previous gains and samples, stopping at other sizes), against each
    system's own search: the faults are identified, after searches that accept nothing, that clip
    or box fitted gains, and that put a gain back at 1 (no window of these is ambiguous: the random
    systems have those)."""
    events: Counter[str] = Counter()
    for systems, previous, samples in searched:
        events += check_stack(systems, previous, samples)
        accepted = [h for s, p, n in zip(systems, previous, samples, strict=True) for h in searched_alone(s, p, n)]
        if accepted:  # as decide_gains decides: several kinds of change, or gains not resolved
            events["ambiguous window" if _unambiguous(accepted, WINDOW, 0.05) is None else "identified"] += 1
    every = [(s, p, n) for systems, previous, samples in searched for s, p, n in zip(systems, previous, samples)]
    systems, previous, samples = zip(*every, strict=True)
    check_stack(list(systems), np.array(previous), list(samples))
    assert len(searched) >= 20 and len(every) >= 500, (len(searched), len(every))
    for event in ("accepted at size 1", "stopped by rest at size 0", "clipped", "boxed", "back to 1", "identified"):
        assert events[event] >= 1, str(sorted(events.items()))


def searched_alone(system, previous, samples):
    return gain_hypotheses(system, ALPHA, LOWER, UPPER, previous, samples)


def test_the_windows_of_several_runs_searched_together_are_each_ones_own(searched):
    """``searched_windows`` of the run's searches at once, by window, against each alone."""
    searches = [(systems, samples, previous[0]) for systems, previous, samples in searched]
    together = searched_windows(searches, ALPHA, LOWER, UPPER)
    for (systems, samples, before), found in zip(searches, together, strict=True):
        expected = [
            h for s, n in zip(systems, samples, strict=True) for h in gain_hypotheses(s, ALPHA, LOWER, UPPER, before, n)
        ]
        assert_same(found, [tuple(h) for h in expected])


def test_the_whole_windows_of_several_runs_are_each_ones_own():
    """``window_systems`` (a batch's runs) against ``window_system`` of each window."""
    sigma = np.array([0.01, 0.02, 0.01, 0.03])
    window = gain_test_window(A, np.hstack([B, np.ones((3, 1))]), E, C, sigma, WINDOW, 10)
    windows = [linear_window(np.array([0.6, 0.75, 1.0, 1.0]), WINDOW, seed=seed) for seed in range(6)]
    ys = np.stack([y for y, _ in windows])
    us = np.stack([np.hstack([u, np.ones((WINDOW, 1))]) for _, u in windows])
    for k, found in enumerate(window_systems(window, ys, us)):
        one = window_system(window, ys[k], us[k])
        assert all(np.array_equal(a, b) for a, b in zip(found, one, strict=True))
