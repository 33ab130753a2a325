"""Least squares within a box, for the few unknowns of the reconciliators' gain estimators.

The gain estimators solve min ‖R β − c‖² over lower ≤ β ≤ upper with one unknown per sensor, every
tick, often with a bound active (a healthy sensor's β = 1 sits on it). scipy's BVLS solves it, but
its Python set-up costs ten times the algebra of a 4 × 4 problem; the primal active-set method below
does the same on the small system, and hands anything it cannot settle quickly to BVLS. Its
subproblems go straight to LAPACK (numpy.linalg's checks cost more than a 4 × 4 solve).
"""

from __future__ import annotations

import numpy as np
import scipy.optimize
from scipy.linalg import lapack

from estimators.batched import mv

_EPS = float(np.finfo(float).eps)


def box_least_squares(R: np.ndarray, c: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """argmin ‖R β − c‖² subject to lower ≤ β ≤ upper (elementwise, lower < upper).

    Shapes: R (k, m), c (k,), lower and upper (m,); returns β (m,).

    The primal active-set method for a convex quadratic program (Nocedal & Wright, Numerical
    Optimization, 2nd ed., Algorithm 16.3) with the bounds as the constraints: from the
    unconstrained minimizer clipped to the box, minimize over the variables not held at a bound
    (least squares on their columns); if that leaves the box, move towards it until the first
    variable reaches its bound and hold it there; otherwise release a held variable whose
    multiplier, the gradient g = Rᵀ(R β − c), pulls it into the box (g_i < 0 at its lower bound,
    g_i > 0 at its upper), or stop: β then satisfies the KKT conditions, and is the minimizer (the
    only one if R has full column rank). A rank-deficient R, or a problem not settled in 3 m + 3
    iterations, goes to scipy's BVLS; so does a numerically rank-deficient R (σ_min ≤ m ε σ_max), after
    the minimum-norm least-squares solution, if that lies in the box.
    """
    k, m = R.shape
    sv = lapack.dgesvd(R, compute_uv=0)[1].tolist()
    if k < m or not sv[-1] > sv[0] * m * _EPS:
        beta = np.linalg.lstsq(R, c, rcond=None)[0]
        inside = np.all(beta >= lower) and np.all(beta <= upper)
        return beta if inside else _bvls(R, c, lower, upper)
    beta = _least_squares(R, c)
    # The bookkeeping is on m numbers: Python floats and lists cost less than numpy calls there.
    lo, hi, x = lower.tolist(), upper.tolist(), beta.tolist()
    if all(a <= v <= b for a, v, b in zip(lo, x, hi, strict=True)):
        return beta
    x = [min(max(v, a), b) for a, v, b in zip(lo, x, hi, strict=True)]
    held = [v in (a, b) for a, v, b in zip(lo, x, hi, strict=True)]
    # A multiplier smaller than the rounding of the gradient does not release its variable.
    tolerance = 1e-12 * sv[0] * (sv[0] * max(map(abs, x)) + max(map(abs, c.tolist())))
    for _ in range(3 * m + 3):
        free = [i for i in range(m) if not held[i]]
        z = list(x)
        if free:
            fixed = R.dot(np.array([v if h else 0.0 for v, h in zip(x, held, strict=True)]))
            for i, v in zip(free, _least_squares(R[:, free], c - fixed).tolist(), strict=True):
                z[i] = v
        first, reach, bound = -1, 1.0, 0.0  # the first variable z takes past a bound, along x → z
        for i in free:
            edge = lo[i] if z[i] < lo[i] else hi[i] if z[i] > hi[i] else None
            if edge is not None and (along := (edge - x[i]) / (z[i] - x[i])) < reach:
                first, reach, bound = i, along, edge
        if first >= 0:
            x = [a + reach * (b - a) for a, b in zip(x, z, strict=True)]
            x[first], held[first] = bound, True
            continue
        x = z
        g = R.T.dot(R.dot(np.array(x)) - c).tolist()
        pull, release = tolerance, -1  # the held variable its multiplier pulls hardest into the box
        for i in range(m):
            inward = -g[i] if x[i] <= lo[i] else g[i]  # > 0: moving into the box lowers the cost
            if held[i] and inward > pull:
                pull, release = inward, i
        if release < 0:
            return np.array(x)
        held[release] = False
    return _bvls(R, c, lower, upper)


def _least_squares(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """argmin ‖A x − b‖ for A (k, n) of full column rank, k ≥ n, by Householder QR (LAPACK's dgels)."""
    solution = lapack.dgels(A, b)[1]
    return solution[: A.shape[1]]


def _bvls(R: np.ndarray, c: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    solution = scipy.optimize.lsq_linear(R, c, bounds=(lower, upper), method="bvls").x
    return np.minimum(np.maximum(solution, lower), upper)  # BVLS may step past a bound by a rounding


def box_least_squares_runs(
    R: np.ndarray, c: np.ndarray, lower: np.ndarray, upper: np.ndarray, failed: dict[int, str] | None = None
) -> np.ndarray:
    """``box_least_squares`` of K problems of one size at once (a batch's runs): R (K, k, m) (each
    as the single call would have it: a product rounds by its memory order), c (K, k), the box
    (m,) shared; returns β (K, m), each run's bit for bit.

    The same method on arrays: LAPACK's SVD and least squares run by run, the bookkeeping of the
    active set (which variable reaches its bound first, which held one to release) as masks over the
    runs still iterating, the first index winning a tie as the loop over i has it. A run that is
    rank-deficient, not finite, or not settled in 3 m + 3 iterations is handed to
    ``box_least_squares``. With ``failed``, a run it holds is not solved (β NaN) and one whose
    problem raises is recorded there; without, it raises."""
    runs, k, m = R.shape
    skip = np.zeros(runs, dtype=bool)
    skip[list(failed or ())] = True
    sv = np.stack([np.zeros(min(k, m)) if no else lapack.dgesvd(Rk, compute_uv=0)[1] for Rk, no in zip(R, skip)])
    alone = skip.copy() if k >= m else np.ones(runs, dtype=bool)  # solved alone (or not at all)
    alone |= ~(sv[:, -1] > sv[:, 0] * m * _EPS)
    beta = np.stack([np.zeros(m) if no else _least_squares(Rk, ck) for Rk, ck, no in zip(R, c, alone, strict=True)])
    alone |= ~np.isfinite(beta).all(axis=1) | ~np.isfinite(c).all(axis=1)
    x = np.minimum(np.maximum(beta, lower), upper)
    going = ~alone & (x != beta).any(axis=1)  # outside the box: the active set
    x = _active_set(R, c, lower, upper, x, sv[:, 0], going)
    for r in np.flatnonzero((alone | going) & ~skip):  # as the single call (after 3 m + 3 iterations: BVLS)
        x[r] = _alone(R[r], c[r], lower, upper, failed, int(r))
    x[skip] = np.nan
    return x


def _alone(
    R: np.ndarray, c: np.ndarray, lower: np.ndarray, upper: np.ndarray, failed: dict[int, str] | None, r: int
) -> np.ndarray | float:
    """Run r's problem by ``box_least_squares``; with ``failed``, an error is recorded there (β NaN)."""
    if failed is None:
        return box_least_squares(R, c, lower, upper)
    try:
        return box_least_squares(R, c, lower, upper)
    except Exception as error:  # noqa: BLE001 (recorded: that run fails, as alone)
        failed[r] = f"{type(error).__name__}: {error}"
        return np.nan


def _active_set(
    R: np.ndarray,
    c: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    x: np.ndarray,
    sv_max: np.ndarray,
    going: np.ndarray,
) -> np.ndarray:
    """``box_least_squares``'s iterations in the runs ``going`` from the clipped x (K, m); the runs
    still going after 3 m + 3 iterations are left in ``going``."""
    runs, m = x.shape
    held = (x == lower) | (x == upper)
    tolerance = 1e-12 * sv_max * (sv_max * np.max(np.abs(x), axis=1) + np.max(np.abs(c), axis=1))
    every = np.arange(runs)
    for _ in range(3 * m + 3):
        rows = np.flatnonzero(going)
        if not len(rows):
            break
        z = x.copy()
        fixed = mv(R, np.where(held, x, 0.0))
        for r in rows:
            free = np.flatnonzero(~held[r])
            if len(free):
                z[r, free] = _least_squares(R[r][:, free], c[r] - fixed[r])
        with np.errstate(divide="ignore", invalid="ignore"):
            edge = np.where(z < lower, lower, np.where(z > upper, upper, np.nan))
            along = np.where(~held & ~np.isnan(edge), (edge - x) / (z - x), np.inf)
        first = np.argmin(along, axis=1)  # the first variable z takes past a bound, along x → z
        reach = along[every, first]
        steps = going & (reach < 1.0)  # it reaches its bound on the way: hold it there
        x[steps] = x[steps] + reach[steps, None] * (z[steps] - x[steps])
        x[steps, first[steps]] = edge[steps, first[steps]]
        held[steps, first[steps]] = True
        settle = going & ~steps
        x[settle] = z[settle]
        g = mv(np.swapaxes(R, 1, 2), mv(R, x) - c)
        inward = np.where(x <= lower, -g, g)  # > 0: moving into the box lowers the cost
        inward = np.where(held & ~np.isnan(inward), inward, -np.inf)
        release = np.argmax(inward, axis=1)  # the held variable its multiplier pulls hardest into the box
        pulled = settle & (inward[every, release] > tolerance)
        held[pulled, release[pulled]] = False
        going[:] = steps | pulled
    return x
