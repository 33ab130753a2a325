"""LAPACK on stacks (``estimators.stacked``): a matrix's numbers in a stack of K are those it gets
alone, and they are the numbers np.linalg gives, to rounding."""

from __future__ import annotations

import numpy as np
import pytest

from estimators.stacked import least_squares, singular_values, triangular_factors


def stack(rng: np.random.Generator, K: int, k: int, n: int) -> np.ndarray:
    """K matrices (k, n) with column scales over six decades."""
    return rng.normal(size=(K, k, n)) * 10.0 ** rng.uniform(-3, 3, (K, 1, n))


@pytest.mark.parametrize("seed", range(4))
def test_a_matrix_in_a_stack_gets_its_own_numbers(seed):
    rng = np.random.default_rng(seed)
    for _ in range(60):
        n = int(rng.integers(1, 6))
        k = n + int(rng.integers(0, 4))
        K = int(rng.integers(1, 40))
        A, b = stack(rng, K, k, n), rng.normal(size=(K, k))
        square = np.triu(stack(rng, K, n, n))  # the reconciliators' reduced systems: triangular
        for function, arguments in (
            (singular_values, (A,)),
            (triangular_factors, (A,)),
            (least_squares, (A, b)),
            (least_squares, (square, b[:, :n])),
        ):
            together = function(*arguments)
            for r in range(K):
                np.testing.assert_array_equal(together[r], function(*(a[r] for a in arguments)))


def test_they_are_numpy_linalg_s_numbers_to_rounding():
    rng = np.random.default_rng(11)
    for _ in range(300):
        n = int(rng.integers(1, 6))
        k = n + int(rng.integers(0, 4))
        A, b = stack(rng, 1, k, n)[0], rng.normal(size=k)
        np.testing.assert_allclose(singular_values(A), np.linalg.svd(A, compute_uv=False), rtol=1e-13)
        R = triangular_factors(A)
        np.testing.assert_array_equal(R, np.triu(R))  # exact zeros below the diagonal
        reference_factor = np.abs(np.linalg.qr(A, mode="r"))
        np.testing.assert_allclose(np.abs(R), reference_factor, rtol=1e-12, atol=1e-13 * np.abs(R).max())
        x, reference = least_squares(A, b), np.linalg.lstsq(A, b, rcond=None)[0]
        # the error bound of a least-squares solution: cond(A) times the rounding, on each column's scale
        scale = np.linalg.norm(A, axis=0)
        condition = np.linalg.cond(A / scale)
        bound = 1e-13 * condition**2 * (1 + np.abs(reference * scale).max())
        np.testing.assert_allclose(x * scale, reference * scale, atol=bound)


def test_a_singular_triangular_factor_gives_nan():
    with np.errstate(invalid="ignore"):
        assert np.isnan(least_squares(np.zeros((4, 2)), np.ones(4))).all()
        assert np.isnan(least_squares(np.zeros((3, 3)), np.ones(3))).all()


def test_overwrite_factors_the_given_array_in_place():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(2, 6, 3))
    expected = triangular_factors(A)
    work = np.asfortranarray(A[1]).copy(order="F")
    np.testing.assert_array_equal(triangular_factors(work, overwrite=True), expected[1])
    assert not np.array_equal(work, A[1])  # LAPACK's factors were written into it


def test_without_numpy_s_gufuncs_the_public_functions_give_the_same_numbers(monkeypatch):
    """A NumPy whose gufuncs have other names (before 2.0) goes through np.linalg, which calls the
    same LAPACK routines: the same numbers (a singular factor NaN as well)."""
    import estimators.stacked as stacked

    rng = np.random.default_rng(5)
    A, b, square = stack(rng, 6, 5, 3), rng.normal(size=(6, 5)), np.triu(stack(rng, 6, 3, 3))
    expected = [singular_values(A), triangular_factors(A), least_squares(A, b), least_squares(square, b[:, :3])]
    for name in ("_svd", "_qr_r_raw", "_solve1"):
        monkeypatch.setattr(stacked, name, None)
    found = [singular_values(A), triangular_factors(A), least_squares(A, b), least_squares(square, b[:, :3])]
    for got, want in zip(found, expected, strict=True):
        np.testing.assert_array_equal(got, want)
    assert np.isnan(least_squares(np.zeros((4, 2)), np.ones(4))).all()
