"""Least squares within a box, for the few unknowns of the reconciliators' gain estimators.

The gain estimators solve min ‖R β − c‖² over lower ≤ β ≤ upper with one unknown per sensor, every
tick, often with a bound active (a healthy sensor's β = 1 sits on it). scipy's BVLS solves it, but
its Python set-up costs ten times the algebra of a 4 × 4 problem; the primal active-set method below
does the same on the small system, and hands anything it cannot settle quickly to BVLS. Its
LAPACK calls go through ``estimators.stacked`` (numpy.linalg's checks cost more than a 4 × 4
solve), which also lets K problems of a batch make each call once (``box_least_squares_runs``).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.optimize

from estimators.stacked import least_squares, singular_values

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
    the minimum-norm least-squares solution, if that lies in the box; so does a subproblem whose
    solution is not finite.
    """
    R, c = np.ascontiguousarray(R, dtype=float), np.asarray(c, dtype=float)  # its products' kernels: row-major
    k, m = R.shape
    sv = singular_values(R).tolist()
    if k < m or not sv[-1] > sv[0] * m * _EPS:
        beta = np.linalg.lstsq(R, c, rcond=None)[0]
        inside = np.all(beta >= lower) and np.all(beta <= upper)
        return beta if inside else _bvls(R, c, lower, upper)
    beta = least_squares(R, c)
    # The bookkeeping is on m numbers: Python floats and lists cost less than numpy calls there.
    lo, hi, x = lower.tolist(), upper.tolist(), beta.tolist()
    if all(a <= v <= b for a, v, b in zip(lo, x, hi, strict=True)):
        return beta
    if not all(map(math.isfinite, x)):
        return _bvls(R, c, lower, upper)
    x = [min(max(v, a), b) for a, v, b in zip(lo, x, hi, strict=True)]
    # A multiplier smaller than the rounding of the gradient does not release its variable.
    tolerance = 1e-12 * sv[0] * (sv[0] * max(map(abs, x)) + max(map(abs, c.tolist())))
    found = _active_set(R, c, lo, hi, x, tolerance)
    return _bvls(R, c, lower, upper) if found is None else found


def _active_set(
    R: np.ndarray, c: np.ndarray, lo: list[float], hi: list[float], x: list[float], tolerance: float
) -> np.ndarray | None:
    """``box_least_squares``'s iterations from x in the box, those at a bound held; None: not settled
    in 3 m + 3 iterations, or a subproblem with no finite solution."""
    m = len(x)
    held = [v in (a, b) for a, v, b in zip(lo, x, hi, strict=True)]
    for _ in range(3 * m + 3):
        free = [i for i in range(m) if not held[i]]
        z = list(x)
        if free:
            fixed = R.dot(np.array([v if h else 0.0 for v, h in zip(x, held, strict=True)]))
            solution = least_squares(R[:, free], c - fixed).tolist()
            if not all(map(math.isfinite, solution)):
                return None
            for i, v in zip(free, solution, strict=True):
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
    return None


def _bvls(R: np.ndarray, c: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    solution = scipy.optimize.lsq_linear(R, c, bounds=(lower, upper), method="bvls").x
    return np.minimum(np.maximum(solution, lower), upper)  # BVLS may step past a bound by a rounding


def box_least_squares_runs(
    R: np.ndarray, c: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``box_least_squares`` of K problems (a batch's runs), each bit for bit what it gives alone
    (both lay R out row-major in float64, whose products' kernels depend on the layout).

    Shapes: R (K, k, m), c (K, k), lower and upper (m,) or (K, m); returns β (K, m) and the runs
    left to ``box_least_squares`` (bool, K; their rows of β NaN): those whose R is rank deficient or
    has fewer rows than columns, whose numbers are not all finite, whose subproblem has no finite
    solution, or whose active set is not settled in 3 m + 3 iterations (which go to BVLS alone too).

    The same primal active-set method, its bookkeeping on (K, m) arrays: every run takes its own
    steps (a step to the box, or a release); the singular values of all runs in one call, the
    subproblems of the runs that hold the same variables in one call (``estimators.stacked``: each
    run's numbers are those it gets alone), the products Rᵀ(R β − c) by NumPy's stacked matmul,
    which calls the single product's kernel per run.
    """
    R, c = np.ascontiguousarray(R, dtype=float), np.asarray(c, dtype=float)  # as ``box_least_squares`` lays them out
    runs, k, m = R.shape
    beta = np.full((runs, m), np.nan)
    if k < m or not runs:
        return beta, np.full(runs, k < m)
    lo, hi = np.empty((runs, m)), np.empty((runs, m))
    lo[:], hi[:] = lower, upper
    # Sums: a NaN or an infinity anywhere shows in them (so can an overflow: that run goes alone too).
    finite = np.isfinite(R.sum(axis=(1, 2)) + c.sum(axis=1) + lo.sum(axis=1) + hi.sum(axis=1))
    sv = np.zeros((runs, m))
    sv[finite] = singular_values(R[finite])
    regular = finite & (sv[:, -1] > sv[:, 0] * m * _EPS)
    x = np.zeros((runs, m))
    x[regular] = least_squares(R[regular], c[regular])
    unsolved = regular & ~np.isfinite(x.sum(axis=1))
    regular &= ~unsolved
    inside = regular & ((lo <= x) & (x <= hi)).all(axis=1)
    beta[inside] = x[inside]
    search = _ActiveSets(np.flatnonzero(regular & ~inside), R, c, lo, hi, x, sv[:, 0])
    for _ in range(3 * m + 3):
        if not len(search.rows):
            break
        search.iterate(beta, unsolved)
    alone = ~regular | unsolved  # not finite, rank deficient, or a subproblem unsolved
    alone[search.rows] = True  # not settled in 3 m + 3 iterations
    return beta, alone


class _ActiveSets:
    """The runs of ``box_least_squares_runs`` still searching, a row each: their problems (R, c, the
    box), iterates x in the box, the variables each holds at a bound, and release tolerances."""

    def __init__(self, rows: np.ndarray, *problems: np.ndarray) -> None:
        """The runs ``rows`` of R, c, lo, hi, the unconstrained minimizers x and σ_max (all runs')."""
        R, c, lo, hi, x, top = (a[rows] for a in problems)
        self.rows, self.R, self.c, self.lo, self.hi = rows, R, c, lo, hi
        x = np.where(lo > x, lo, x)  # Python's max(v, a) and min(v, b), as alone (-0.0 kept against 0.0)
        self.x = np.where(hi < x, hi, x)
        self.held = (self.x == lo) | (self.x == hi)
        # A multiplier smaller than the rounding of the gradient does not release its variable.
        self.tolerance = (1e-12 * top * (top * np.abs(self.x).max(axis=1) + np.abs(self.c).max(axis=1)))[:, None]

    def keep(self, kept: np.ndarray) -> None:
        """Only the runs where ``kept`` (a mask over the runs still searching) go on."""
        for name in ("rows", "R", "c", "lo", "hi", "x", "held", "tolerance"):
            setattr(self, name, getattr(self, name)[kept])

    def iterate(self, beta: np.ndarray, unsolved: np.ndarray) -> None:
        """One iteration of every run: a step towards its minimizer z until a bound, or z itself
        and a release, or done (its row of ``beta`` written, the run dropped). Every run's step and
        release are formed; each run takes the one it takes."""
        z, broken = self.minimizers()
        if broken.any():  # alone, it goes to BVLS
            unsolved[self.rows[broken]] = True
            self.keep(~broken)
            z = z[~broken]
        x, lo, hi, held, R = self.x, self.lo, self.hi, self.held, self.R
        edge = np.where(z < lo, lo, hi)
        outside = ~held & ((z < lo) | (z > hi))
        along = np.divide(edge - x, z - x, out=np.full(x.shape, np.inf), where=outside)  # where x → z meets it
        along[np.isnan(along)] = np.inf  # ∞/∞ near overflow: alone, `along < reach` passes it over
        each = np.arange(len(x))
        first = along.argmin(axis=1)  # the first variable z takes past a bound (the lowest index of a tie)
        reach = along[each, first]
        step = reach < 1.0
        stepped = x + np.where(step, reach, 0.0)[:, None] * (z - x)
        stepped[each, first] = edge[each, first]
        g = np.matmul(np.swapaxes(R, 1, 2), (np.matmul(R, z[..., None])[..., 0] - self.c)[..., None])[..., 0]
        inward = np.where(z <= lo, -g, g)  # > 0: moving into the box lowers the cost
        pulled = np.where(held & (inward > self.tolerance), inward, -np.inf)
        release = pulled.argmax(axis=1)  # the held variable its multiplier pulls hardest into the box
        released = ~step & (pulled[each, release] > -np.inf)
        done = ~step & ~released
        beta[self.rows[done]] = z[done]
        self.x = np.where(step[:, None], stepped, z)
        held[each, first] |= step
        held[each, release] &= ~released
        if done.any():
            self.keep(~done)

    def minimizers(self) -> tuple[np.ndarray, np.ndarray]:
        """z, each run's least squares over the variables it does not hold (the others held), the
        runs that hold the same ones solved in one call; and the runs whose z is not finite."""
        held, z = self.held, self.x.copy()
        if held.all():
            return z, np.zeros(len(z), dtype=bool)
        pattern = _patterns(held)
        rhs = self.c - np.matmul(self.R, np.where(held, self.x, 0.0)[..., None])[..., 0]
        for code in np.unique(pattern).tolist():
            group = np.flatnonzero(pattern == code)
            free = np.flatnonzero(~held[group[0]])
            if len(free):
                z[np.ix_(group, free)] = least_squares(self.R[group][:, :, free], rhs[group])
        return z, ~np.isfinite(z.sum(axis=1))


def _patterns(held: np.ndarray) -> np.ndarray:
    """A number for each row of ``held`` (K, m), equal for equal rows: its bits, or for m > 62 (more
    than an int64 holds) the row's index among the distinct rows."""
    if held.shape[1] <= 62:
        return held.dot(1 << np.arange(held.shape[1], dtype=np.int64))
    return np.unique(held, axis=0, return_inverse=True)[1].ravel()
