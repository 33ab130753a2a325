"""The gain test's search for what changed (docs/three-tank.md, "The gain test"): the hypotheses
with the fewest fitted gains that a window system does not reject, searched over a stack of
systems at once (a window's own system and its splits', those of every run of a batch that
searches at one tick).

The search of one system goes size by size (0 … m fitted gains), through every set of fitted gains
and every choice of which other gains go back to 1, and stops at the first size that accepts
something, or as soon as the part of the statistic no β explains exceeds the size's threshold. Over
a stack the hypotheses stay a Python loop (by size, then by free set and back pattern) and each is
computed for every system still searching, in stacked arrays: a system's stops are masks, its own
back patterns (only gains whose previous value is not 1 can go back) a filter, and the bounded
refits (a clip for one gain, ``box_least_squares`` for more) are done only on the systems that need
them. Each system's accepted list is bit for bit what its search alone gives (the same floats, in
the same order): every stacked product is NumPy's stacked ``matmul`` on operands laid out per matrix
as the one-system code lays them out (the fitted columns of R in Fortran order, their Gram matrix
by the same symmetric-rank-k call), which runs the same BLAS call per matrix
(tests/test_gain_hypotheses.py).
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import scipy.special

from estimators.batched import mv
from estimators.box_least_squares import box_least_squares
from estimators.lmi import pseudo_inverse, pseudo_inverses


class GainHypothesis(NamedTuple):
    """A hypothesis about a window's gains: those in ``free`` changed to unknown values, each of the
    others is either as before (the previous γ̂) or back to 1."""

    beta: np.ndarray
    """β̂ = 1/γ̂: fitted for the sensors in ``free``, given for the others."""
    free: tuple[int, ...]
    statistic: float
    """T(β̂)."""
    p_value: float
    """P(χ²(dof − |free|) > T(β̂)): the probability of a statistic this large if the hypothesis holds."""
    standard_error: float
    """The largest standard error of the fitted β̂ (0 if none is fitted)."""
    samples: int
    """The samples after the change the hypothesis places (the window's length if none)."""

    @property
    def kind(self) -> tuple[tuple[int, ...], tuple[bool, ...]]:
        """Which gains it fits, and which of the others it puts at 1."""
        return self.free, tuple(bool(b == 1.0) for j, b in enumerate(self.beta) if j not in self.free)


@functools.lru_cache(maxsize=1024)
def chi2_quantile(alpha: float, dof: int) -> float:
    """The (1 − α) quantile of χ²(dof): the threshold of a test at level α."""
    return float(scipy.special.chdtri(dof, alpha))


class SystemStack(NamedTuple):
    """S window systems (``gain_identification.WindowSystem``) stacked, with what each one's search
    is given: T(β) = ‖factor β − rotated‖² + rest, χ²(dof) at the true β."""

    factor: np.ndarray
    """R of each system, (S, m, m), C order."""
    rotated: np.ndarray
    """(S, m)."""
    rest: np.ndarray
    """(S,)."""
    dof: np.ndarray
    """(S,), integers."""
    previous: np.ndarray
    """β before the change, (S, m): a gain not fitted is at its previous value or back at 1."""
    samples: Sequence[int]
    """The samples after the change each system places (``GainHypothesis.samples``)."""


def stacked_hypotheses(
    stack: SystemStack, alpha: float, lower: np.ndarray, upper: np.ndarray
) -> list[list[GainHypothesis]]:
    """The hypotheses with the fewest fitted gains that each system of ``stack`` does not reject at
    level α, by system; none for a system that rejects every one (no constant gains explain it).

    Each sensor's gain is either fitted (least squares; within [lower, upper] on β, both (m,)), or
    given: its previous β, or 1 (healthy). With |S| gains fitted, T(β̂) ~ χ²(dof − |S|) if the
    hypothesis holds, so a true hypothesis is rejected with probability α: a gain differs from its
    previous value, or from 1, only if every hypothesis that keeps it is rejected."""
    systems, m = stack.rotated.shape
    found: list[list[GainHypothesis]] = [[] for _ in range(systems)]
    searching = np.ones(systems, dtype=bool)
    columns = np.ascontiguousarray(np.swapaxes(stack.factor, 1, 2))  # row j: column j of R
    recovered = (stack.previous != 1.0) @ (1 << np.arange(m))  # bit j: gain j may go back to 1
    for size in range(m + 1):
        rows = np.flatnonzero(searching)
        thresholds = _thresholds(alpha, stack.dof[rows] - size)
        # Every statistic is rest + a square, and the thresholds only fall as more gains are fitted:
        # a system whose rest exceeds this size's threshold can accept nothing of this size or larger.
        hopeless = stack.rest[rows] > thresholds
        searching[rows[hopeless]] = False
        rows, thresholds = rows[~hopeless], thresholds[~hopeless]
        if not len(rows):
            break
        accepted = _search_size(stack, columns, rows, recovered[rows], thresholds, size, lower, upper)
        for k, hypothesis in accepted:
            found[k].append(hypothesis)
        searching[[k for k, _ in accepted]] = False  # a size that accepts something ends the search
    return found


class _Cases(NamedTuple):
    """The (hypothesis, system) pairs of one size, hypothesis by hypothesis (free set, then back
    pattern, in the one-system search's order)."""

    frees: list[tuple[int, ...]]
    free: np.ndarray
    """Each case's free set, an index into ``frees``."""
    back: np.ndarray
    """Each case's gains put back at 1, (cases, m) booleans."""
    at: np.ndarray
    """Each case's system, an index into the size's rows."""


def _cases(m: int, size: int, recovered: np.ndarray) -> _Cases:
    """Every hypothesis of ``size`` fitted gains for the systems whose gains that may go back to 1
    are the bits of ``recovered``: a back pattern is a system's if it puts back only such gains."""
    frees = list(itertools.combinations(range(m), size))
    groups = {bits: np.flatnonzero(recovered == bits) for bits in set(recovered.tolist())}
    free, back, at = [], [], []
    for f, fitted in enumerate(frees):
        others = [j for j in range(m) if j not in fitted]
        for pattern in itertools.product((False, True), repeat=len(others)):
            bits = sum(1 << j for j, b in zip(others, pattern, strict=True) if b)
            for allowed, members in groups.items():
                if not bits & ~allowed:
                    free.append(np.full(len(members), f))
                    back.append(np.full(len(members), bits))
                    at.append(members)
    backs = (np.concatenate(back)[:, None] >> np.arange(m)) & 1 == 1
    return _Cases(frees, np.concatenate(free), backs, np.concatenate(at))


def _search_size(
    stack: SystemStack,
    columns: np.ndarray,
    rows: np.ndarray,
    recovered: np.ndarray,
    thresholds: np.ndarray,
    size: int,
    lower: np.ndarray,
    upper: np.ndarray,
) -> list[tuple[int, GainHypothesis]]:
    """The hypotheses of ``size`` fitted gains that the systems ``rows`` accept (each at its
    threshold), as (system, hypothesis) in each system's order."""
    m = stack.rotated.shape[1]
    cases = _cases(m, size, recovered)
    system = rows[cases.at]
    factor, rotated, rest = stack.factor[system], stack.rotated[system], stack.rest[system]
    threshold = thresholds[cases.at]
    beta = stack.previous[system]
    beta[cases.back] = 1.0
    error = np.zeros(len(system))
    if size:
        index = np.array(cases.frees)[cases.free]  # (cases, size): the fitted gains
        fitted_columns, covariance, errors = _normal_equations(columns, rows, cases.frees)
        pair = cases.free * len(rows) + cases.at  # the case's (free set, system)
        beta, rejected = _fit(
            factor, rotated, rest, beta, index, fitted_columns[pair], covariance[pair], threshold, lower, upper
        )
        error = errors[pair]
    else:
        rejected = np.zeros(len(system), dtype=bool)
    statistic = _statistics(factor, rotated, rest, beta)
    accepted = np.flatnonzero(~rejected & (statistic <= threshold))
    p = scipy.special.chdtrc(stack.dof[system[accepted]] - size, statistic[accepted]).tolist()
    betas = beta[accepted]
    return [
        (k, GainHypothesis(b, cases.frees[f], s, v, e, stack.samples[k]))
        for k, b, f, s, v, e in zip(
            system[accepted].tolist(),
            betas,
            cases.free[accepted].tolist(),
            statistic[accepted].tolist(),
            p,
            error[accepted].tolist(),
            strict=True,
        )
    ]


def _normal_equations(
    columns: np.ndarray, rows: np.ndarray, frees: list[tuple[int, ...]]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each free set (outer) and system of ``rows`` (inner): the fitted columns of R, transposed
    (C order: R[:, index] is in Fortran order), (XᵀX)⁺ and the largest standard error √max diag."""
    chosen = np.ascontiguousarray(np.swapaxes(columns[rows][:, frees], 0, 1))  # (frees, rows, size, m)
    fitted = chosen.reshape(-1, *chosen.shape[2:])
    covariance = normal_inverses(np.matmul(fitted, np.swapaxes(fitted, 1, 2)))  # Xᵀ X: one syrk each
    diagonal = np.diagonal(covariance, axis1=1, axis2=2)
    largest = diagonal[:, 0]
    for j in range(1, diagonal.shape[1]):  # max()'s order over the list: the first of equals, NaN kept first
        largest = np.where(diagonal[:, j] > largest, diagonal[:, j], largest)
    if np.any(largest < 0.0):
        raise ValueError("math domain error")  # math.sqrt's, as the one-system search raises
    return fitted, covariance, np.sqrt(largest)


def _fit(
    factor: np.ndarray,
    rotated: np.ndarray,
    rest: np.ndarray,
    beta: np.ndarray,
    index: np.ndarray,
    fitted_columns: np.ndarray,
    covariance: np.ndarray,
    threshold: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """β with the gains ``index`` fitted (least squares, then within the box where it leaves it),
    and which cases are rejected already by the unbounded fit (the box can only make it worse)."""
    np.put_along_axis(beta, index, 0.0, axis=1)
    rhs = rotated - mv(factor, beta)
    fitted = mv(covariance, mv(fitted_columns, rhs))
    np.put_along_axis(beta, index, fitted, axis=1)
    low, high = lower[index], upper[index]
    outside = np.any((fitted < low) | (fitted > high), axis=1)
    rejected = np.zeros(len(beta), dtype=bool)
    if outside.any():
        rejected[outside] = (
            _statistics(factor[outside], rotated[outside], rest[outside], beta[outside]) > threshold[outside]
        )
        boxed = np.flatnonzero(outside & ~rejected)
        if index.shape[1] == 1:
            fitted[boxed] = np.clip(fitted[boxed], low[boxed], high[boxed])
        else:
            for k in boxed:
                fitted[k] = box_least_squares(fitted_columns[k].T, rhs[k], low[k], high[k])
        np.put_along_axis(beta, index, fitted, axis=1)
    return beta, rejected


def _statistics(factor: np.ndarray, rotated: np.ndarray, rest: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """T(β) of each case, as ``chi2_statistic`` computes it (residual · residual by the dot kernel)."""
    residual = mv(factor, beta) - rotated
    return np.matmul(residual[:, None, :], residual[:, :, None])[:, 0, 0] + rest


def _thresholds(alpha: float, dof: np.ndarray) -> np.ndarray:
    """``chi2_quantile`` of each degree of freedom."""
    values, inverse = np.unique(dof, return_inverse=True)
    return np.array([chi2_quantile(alpha, d) for d in values.tolist()])[inverse].reshape(dof.shape)


def normal_inverses(grams: np.ndarray) -> np.ndarray:
    """(XᵀX)⁺ of each Gram matrix XᵀX of a stack (P, k, k): for one column 1/‖x‖² (0 for a zero
    column), which is what ``np.linalg.pinv`` returns for a 1 × 1 matrix, bit for bit (tested),
    without its SVD (a gain search makes thousands); else, and where LAPACK's SVD would rescale a
    1 × 1 (near the ends of the floats' range: its last bit may then differ), ``pseudo_inverses``:
    np.linalg.pinv's arithmetic without its checks, LAPACK's SVD matrix by matrix."""
    if grams.shape[1] != 1:
        return pseudo_inverses(grams) if len(grams) else grams.copy()
    g = grams[:, 0, 0]
    inverse = np.zeros_like(grams)
    unscaled = (g > _UNSCALED[0]) & (g < _UNSCALED[1])
    inverse[unscaled, 0, 0] = 1.0 / g[unscaled]
    for p in np.flatnonzero(~unscaled & (g != 0.0)):
        inverse[p] = pseudo_inverse(grams[p])
    return inverse


def normal_inverse(columns: np.ndarray) -> np.ndarray:
    """(XᵀX)⁺ of the columns X (k, l), as ``normal_inverses``."""
    return normal_inverses((columns.T @ columns)[None])[0]


#: Where a 1 × 1 SVD is |a| exactly (LAPACK scales matrices outside about 1e-146 to 1e146).
_UNSCALED = (1e-100, 1e100)
