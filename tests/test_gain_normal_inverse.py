"""The gain test's (XᵀX)⁺ of its fitted columns: for one column the closed form is what
``np.linalg.pinv`` returns, bit for bit, so the gain search's decisions and the frames do not move."""

from __future__ import annotations

import numpy as np

from estimators.gain_test import normal_inverse


def test_one_column_is_pinv_bit_for_bit_and_more_columns_are_pinv():
    rng = np.random.default_rng(41)
    for _ in range(20_000):
        rows = int(rng.integers(1, 300))
        column = rng.standard_normal((rows, 1)) * 10 ** rng.uniform(-150, 150)
        assert np.array_equal(normal_inverse(column), np.linalg.pinv(column.T @ column))
    assert np.array_equal(normal_inverse(np.zeros((5, 1))), np.linalg.pinv(np.zeros((1, 1))))
    several = rng.standard_normal((40, 3))
    assert np.array_equal(normal_inverse(several), np.linalg.pinv(several.T @ several))


def test_several_columns_are_pinv_bit_for_bit():
    """Two to four columns go through ``pseudo_inverse`` (LAPACK's SVD directly): the same numbers
    as ``np.linalg.pinv``, bit for bit, over scales far apart, and for rank-deficient columns."""
    rng = np.random.default_rng(42)
    for _ in range(5_000):
        k = int(rng.integers(2, 5))
        columns = rng.standard_normal((int(rng.integers(k, 60)), k)) * 10.0 ** rng.uniform(-8, 8, k)
        assert np.array_equal(normal_inverse(columns), np.linalg.pinv(columns.T @ columns))
    twice = np.repeat(rng.standard_normal((10, 1)), 2, axis=1)
    assert np.array_equal(normal_inverse(twice), np.linalg.pinv(twice.T @ twice))
