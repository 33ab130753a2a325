"""The reconciliators' bounded least squares against scipy's BVLS, and its KKT conditions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from estimators.box_least_squares import box_least_squares


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
