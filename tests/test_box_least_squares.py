"""The reconciliators' bounded least squares against scipy's BVLS, and its KKT conditions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from estimators.box_least_squares import box_least_squares, box_least_squares_runs


def random_problem(rng: np.random.Generator, rank_deficient: bool = False):
    m = int(rng.integers(1, 6))
    k = m + int(rng.integers(0, 4))
    R = rng.normal(size=(k, m)) @ np.diag(10.0 ** rng.uniform(-3, 3, m))  # condition numbers up to 1e6
    if rank_deficient and m > 1:
        R[:, -1] = R[:, 0]
    c = rng.normal(size=k) * 10.0 ** rng.uniform(-2, 2)
    lower = rng.uniform(-1.0, 0.5, m)
    return R, c, lower, lower + rng.uniform(0.01, 2.0, m)


@pytest.mark.parametrize("rank_deficient", [False, True])
def test_it_reaches_bvls_minimum_within_rounding(rank_deficient):
    rng = np.random.default_rng(7)
    active = 0
    for _ in range(3000):
        R, c, lower, upper = random_problem(rng, rank_deficient)
        beta = box_least_squares(R, c, lower, upper)
        reference = lsq_linear(R, c, bounds=(lower, upper), method="bvls").x
        assert np.all(beta >= lower) and np.all(beta <= upper)
        cost, best = np.sum((R @ beta - c) ** 2), np.sum((R @ reference - c) ** 2)
        assert cost <= best * (1 + 1e-9) + 1e-12 * (c @ c)
        active += np.any((beta == lower) | (beta == upper))
    assert active > 1000  # most problems have a bound active: the active-set path is what is tested


def test_its_solution_satisfies_the_kkt_conditions():
    """At the minimizer the gradient g = Rᵀ(R β − c) vanishes on the free variables, is ≥ 0 at a
    lower bound and ≤ 0 at an upper one."""
    rng = np.random.default_rng(8)
    for _ in range(500):
        R, c, lower, upper = random_problem(rng)
        beta = box_least_squares(R, c, lower, upper)
        g = R.T @ (R @ beta - c)
        scale = 1e-8 * np.abs(R).max() * (np.abs(c).max() + np.abs(R).max() * np.abs(beta).max())
        at_lower, at_upper = beta == lower, beta == upper
        free = ~(at_lower | at_upper)
        assert np.all(np.abs(g[free]) <= scale)
        assert np.all(g[at_lower] >= -scale) and np.all(g[at_upper] <= scale)


def test_an_unconstrained_minimizer_inside_the_box_is_returned_as_is():
    R = np.array([[2.0, 0.0], [0.0, 1.0]])
    np.testing.assert_array_equal(box_least_squares(R, np.array([1.0, 0.5]), np.zeros(2), np.ones(2)), [0.5, 0.5])


def test_k_problems_at_once_give_each_problems_own_solution_bit_for_bit():
    """``box_least_squares_runs`` (a batch's runs) on groups of problems of one size, each as the
    reduced systems of the model window hold R (a block of a larger array, which a product rounds
    by): some inside the box, most with bounds reached on the way and released again, rank-deficient
    ones (handed to the one-problem solver) and one that raises there, recorded in ``failed``."""
    rng = np.random.default_rng(9)
    active = 0
    for trial in range(300):
        m = int(rng.integers(1, 6))
        k, runs = m + int(rng.integers(0, 3)), int(rng.integers(1, 10))
        block = rng.normal(size=(runs, k + 1, m + 1)) @ np.diag(10.0 ** rng.uniform(-2, 2, m + 1))
        R, c = block[:, :k, :m], block[:, :k, m] * 10.0 ** rng.uniform(-1, 1)
        if trial % 7 == 0 and m > 1:
            R[0, :, -1] = R[0, :, 0]
        lower = rng.uniform(-1.0, 0.5, m)
        upper = lower + rng.uniform(0.01, 2.0, m)
        found = box_least_squares_runs(R, c, lower, upper)
        for r in range(runs):
            alone = box_least_squares(R[r], c[r], lower, upper)
            assert np.array_equal(found[r], alone), (trial, r)
            active += np.any((alone == lower) | (alone == upper))
    assert active > 600
    R, c = rng.normal(size=(3, 4, 2)), rng.normal(size=(3, 4))
    R[1, 0, 0] = np.nan  # LAPACK cannot solve it: the one-problem solver raises
    failed: dict[int, str] = {2: "out before"}
    found = box_least_squares_runs(R, c, np.zeros(2), np.ones(2), failed)
    assert set(failed) == {1, 2} and "LinAlgError" in failed[1] and np.isnan(found[1:]).all()
    assert np.array_equal(found[0], box_least_squares(R[0], c[0], np.zeros(2), np.ones(2)))
