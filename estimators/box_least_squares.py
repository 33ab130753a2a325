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
