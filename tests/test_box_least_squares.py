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


def test_k_problems_at_once_give_each_problem_s_own_bits():
    """``box_least_squares_runs`` of K problems of one shape: each row bit for bit
    ``box_least_squares`` of its problem (bounds per problem or shared), or left to it (rank
    deficient, not finite, not settled); those it settles are most of them, with bounds active."""
    rng = np.random.default_rng(9)
    settled = active = 0
    for trial in range(300):
        m = int(rng.integers(1, 6))
        k = m + int(rng.integers(0, 3))
        K = int(rng.integers(1, 40))
        R = rng.normal(size=(K, k, m)) * 10.0 ** rng.uniform(-3, 3, (K, 1, m))
        deficient = rng.random(K) < (0.05 if m > 1 else 0.0)
        R[deficient, :, -1] = R[deficient, :, 0]
        c = rng.normal(size=(K, k)) * 10.0 ** rng.uniform(-2, 2, (K, 1))
        c[rng.random(K) < 0.02, 0] = np.nan
        lower = rng.uniform(-1.0, 0.5, (K, m) if trial % 2 else m)
        upper = lower + rng.uniform(0.01, 2.0, lower.shape)
        beta, alone = box_least_squares_runs(R, c, lower, upper)
        for r in range(K):
            low, high = (lower[r], upper[r]) if trial % 2 else (lower, upper)
            if alone[r]:
                assert np.isnan(beta[r]).all()
                continue
            np.testing.assert_array_equal(beta[r], box_least_squares(R[r], c[r], low, high))
            settled += 1
            active += np.any((beta[r] == low) | (beta[r] == high))
        assert alone[np.isnan(c).any(axis=1)].all()
    assert settled > 5000 and active > 3000


def test_k_problems_with_no_run_or_too_few_rows():
    beta, alone = box_least_squares_runs(np.zeros((0, 3, 2)), np.zeros((0, 3)), np.zeros(2), np.ones(2))
    assert beta.shape == (0, 2) and alone.shape == (0,)
    beta, alone = box_least_squares_runs(np.ones((3, 1, 2)), np.ones((3, 1)), np.zeros(2), np.ones(2))
    assert alone.all() and np.isnan(beta).all()


def test_k_problems_at_once_at_the_edges_alone_s_numbers():
    """Cases a second review found where the K-run form left the scalar's numbers: a -0.0 clipped
    against a bound of 0.0 (Python's max keeps -0.0), more than 62 variables (the held sets keyed by
    bits), ∞/∞ on the way to a bound near overflow, an F-ordered stack (the products' kernels follow
    the layout), integer inputs."""
    bits = lambda a: np.asarray(a, dtype=float).view(np.int64)  # noqa: E731
    cases = []
    cases.append((np.eye(2)[None], np.array([[-0.0, 5.0]]), np.zeros(2), np.ones(2)))
    m = 65
    coupled = np.eye(m)
    coupled[0, 64] = 1.0  # β0 + β64 ≈ c0
    c = np.full((2, m), 0.5)
    c[0, 0], c[0, 64], c[1, 0], c[1, 64] = 4.0, 2.0, -1.0, 0.25  # run 0 holds β0 and β64, run 1 β0 only
    cases.append((np.stack([coupled, coupled]), c, np.zeros(m), np.ones(m)))
    R = np.array([[1.0, 1.2, 0.0], [0.0, 1.0, 0.0], [0.0, 1e-7, 1.0]])
    low, high = np.array([-1.0e308, 0.85e308, 0.0]), np.array([0.92e308, 0.86e308, 2e301])
    with np.errstate(all="ignore"):
        cases.append((R[None], np.array([[-0.12e308, -0.85e308, -2e300]]), low, high))
    rng = np.random.default_rng(4)
    triangles = np.triu(rng.normal(size=(30, 4, 4)) * 10.0 ** rng.uniform(-3, 3, (30, 1, 4)))
    cases.append((np.asfortranarray(triangles), rng.normal(size=(30, 4)) * 3, np.full(4, 0.5), np.full(4, 1.5)))
    cases.append((np.array([[[1, 2], [3, 4], [5, 7]]]), np.array([[1, 2, 4]]), np.array([-1.0, -1.0]), np.ones(2)))
    for R, c, lower, upper in cases:
        with np.errstate(all="ignore"):
            beta, alone = box_least_squares_runs(R, c, lower, upper)
            for r in np.flatnonzero(~alone):
                np.testing.assert_array_equal(bits(beta[r]), bits(box_least_squares(R[r], c[r], lower, upper)))
    integers = cases[-1][0][0], cases[-1][1][0]  # their least squares lies in the box
    expected = np.linalg.lstsq(*(np.asarray(a, dtype=float) for a in integers), rcond=None)[0]
    np.testing.assert_allclose(box_least_squares(*integers, -np.ones(2), np.ones(2)), expected, rtol=1e-12)
