"""The gain test's shortcuts give its numbers bit for bit, so the gain search's decisions and the
frames do not move: (XᵀX)⁺ of its fitted columns (for one column the closed form, else LAPACK's SVD
directly) is what ``np.linalg.pinv`` returns; a split's basis of the offsets' jumps, kept by the
window, is what a fresh window computes."""

from __future__ import annotations

import numpy as np

from estimators.gain_hypotheses import normal_inverse
from estimators.gain_identification import gain_test_window, window_system
from tests.paper_three_tank import TRUE_GAINS, WINDOW, A, B, C, E, linear_window


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


def test_the_gain_tests_split_systems_are_the_same_with_their_jump_bases_cached():
    """A split's basis of the offsets' jumps depends on the window and the split alone: kept after the
    first split (``GainTestWindow.jumps``), it gives bit for bit the system a fresh window computes,
    for other readings too; a window with a missing reading computes its own."""
    sigma = np.array([0.01, 0.02, 0.01, 0.03])
    make = lambda: gain_test_window(A, np.hstack([B, np.ones((3, 1))]), E, C, sigma, WINDOW, 10)  # noqa: E731
    window = make()
    before = 1.0 / np.array([1.0, 0.9, 1.0, 1.0])
    for seed in (3, 4):
        ys, us = linear_window(TRUE_GAINS, WINDOW, seed=seed)
        us = np.hstack([us, np.ones((WINDOW, 1))])
        for change in (1, 17, WINDOW - 10):
            cached = window_system(window, ys, us, change=change, before=before)
            fresh = window_system(make(), ys, us, change=change, before=before)
            assert all(np.array_equal(a, b) for a, b in zip(cached, fresh, strict=True))
    assert sorted(window.jumps) == [(WINDOW, 1), (WINDOW, 17), (WINDOW, WINDOW - 10)]
    ys[5, 2] = np.nan
    gapped = window_system(window, ys, us, change=17, before=before)
    assert gapped.dof == window_system(make(), ys, us, change=17, before=before).dof
    assert len(window.jumps) == 3
