"""LAPACK on stacks of small matrices through NumPy's own gufuncs (those behind np.linalg).

A gufunc calls its LAPACK routine once per matrix of a stack, with the workspace it queries for
the matrices' shape: a matrix gets the same numbers in a stack of K as alone (a stack of one, or a
2-D array). So one function serves a run alone and the K runs of a batch, bit for bit, and a batch
pays one call for K matrices where SciPy's LAPACK wrappers take one matrix a call (about 2 µs each,
more than the arithmetic of a 4 × 4 problem). The single and the batched form of a computation
call the same one of these, never one of them SciPy's wrapper: NumPy and SciPy ship OpenBLAS builds
of their own, whose last bits can differ on another machine. Inputs are taken as float64.

The np.linalg functions call the same gufuncs after checks that cost more than a small matrix's
arithmetic; a NumPy whose gufuncs are not found (renamed before 2.0) goes through them, where one
matrix that fails (singular, not converging) makes the whole stack NaN, and a square system is
solved by QR too.
"""

from __future__ import annotations

import functools
import importlib
from typing import Any

import numpy as np

try:
    _gufuncs: Any = importlib.import_module("numpy.linalg._umath_linalg")
except ImportError:  # pragma: no cover
    _gufuncs = None
_svd = getattr(_gufuncs, "svd", None)  # NumPy >= 2.0 names
_qr_r_raw = getattr(_gufuncs, "qr_r_raw", None)
_solve1 = getattr(_gufuncs, "solve1", None)


def singular_values(matrices: np.ndarray) -> np.ndarray:
    """σ of each matrix of a stack (..., k, m), descending, shape (..., min(k, m)): LAPACK's gesdd
    without vectors. NaN for a matrix on which it does not converge (np.linalg.svd would raise), with
    NumPy's warning of an invalid value unless np.errstate says otherwise."""
    if _svd is None:
        try:
            return np.linalg.svd(matrices, compute_uv=False)
        except np.linalg.LinAlgError:
            return np.full((*matrices.shape[:-2], min(matrices.shape[-2:])), np.nan)
    return _svd(matrices, signature="d->d")


def triangular_factors(matrices: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """R of the Householder QR of each matrix of a stack (..., k, m), k ≥ m, shape (..., m, m),
    upper triangular with exact zeros below: LAPACK's geqrf, as np.linalg.qr(matrices, "r").
    geqrf works in place: with ``overwrite``, on ``matrices`` themselves (any layout) if they are
    float64 and writeable, else on a copy."""
    m = matrices.shape[-1]
    writeable = matrices.dtype == np.float64 and matrices.flags.writeable
    factored = matrices if overwrite and writeable else np.array(matrices, dtype=float)
    if _qr_r_raw is None:
        return np.asarray(np.linalg.qr(factored, mode="r"))[..., :m, :]
    _qr_r_raw(factored, signature="d->d")
    return factored[..., :m, :] * _upper_triangle(m)


def least_squares(matrices: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """argmin ‖A x − b‖ for each system of a stack, A (..., k, n) of full column rank, b (..., k),
    k ≥ n; returns x (..., n), NaN where the triangular factor is singular (with NumPy's warning of
    an invalid value, unless np.errstate says otherwise).

    Householder QR of [A b] (geqrf): its triangular factor is [[T, d], [0, ρ]] with T x = d the
    normal equations' triangular form (d = Qᵀ b), solved by LAPACK's gesv, whose partial pivoting
    takes T's own diagonal (the entries below it are exact zeros), so that it is back substitution.
    The same algorithm as LAPACK's gels (QR, Qᵀ b, triangular solve), to its rounding. A square
    system (k = n) is solved by gesv alone: LU with partial pivoting, which for an upper triangular
    A (the reduced systems of the reconciliators' gain estimators) is back substitution.
    """
    k, n = matrices.shape[-2:]
    if k == n and _solve1 is not None:
        return _solve1(matrices, vectors, signature="dd->d")  # casts to float64 itself
    system = np.concatenate([matrices, vectors[..., None]], axis=-1, dtype=float)  # factored in place: float64
    if _qr_r_raw is None or _solve1 is None:
        factor = np.asarray(np.linalg.qr(system, mode="r"))
        with np.errstate(invalid="ignore"):
            try:
                return np.linalg.solve(factor[..., :n, :n], factor[..., :n, n:])[..., 0]
            except np.linalg.LinAlgError:
                return np.full((*matrices.shape[:-2], n), np.nan)
    _qr_r_raw(system, signature="d->d")
    return _solve1(system[..., :n, :n] * _upper_triangle(n), system[..., :n, n], signature="dd->d")


@functools.lru_cache(maxsize=16)
def _upper_triangle(size: int) -> np.ndarray:
    """1 on and above the diagonal, 0 below: R from geqrf's output (np.triu builds its mask each call)."""
    mask = np.triu(np.ones((size, size)))
    mask.flags.writeable = False
    return mask
