"""An L-stable fourth-order Rosenbrock method with step-size control for an autonomous ODE
dw/dt = f(w) over one sample: ``integrate`` for one run, ``integrate_runs`` for K runs at once,
each run bit for bit what ``integrate`` gives it.

ROS4 in the transformed form of Hairer & Wanner, Solving Ordinary Differential Equations II,
Sec. IV.7, with the L-stable parameters of its Table 7.2 (γ = 0.57282): four stages, three
evaluations of f and one of ∂f/∂w per step, an embedded third-order solution for the error.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
from scipy.linalg import lapack

_GAMMA = 0.57282
_A21, _A31, _A32 = 2.0, 1.867943637803922, 0.2344449711399156
_C21, _C31, _C32 = -7.137615036412310, 2.580708087951457, 0.6515950076447975
_C41, _C42, _C43 = -2.137148994382534, -0.3214669691237626, -0.6949742501781779
_A3 = np.array([_A31, _A32])  # = a₄ⱼ
_C34 = np.array([[_C31, _C32, 0.0], [_C41, _C42, _C43]])
_SOLUTION_AND_ERROR = np.array(
    [
        [2.255570073418735, 0.2870493262186792, 0.4353179431840180, 1.093502252409163],
        [-0.2815431932141155, -0.07276199124938920, -0.1082196201495311, -1.093502252409163],
    ]
)
_CANNOT = "the observer's ODE cannot be integrated to the requested tolerance"


class VectorField(Protocol):
    """dw/dt = f(w) of one run, with ∂f/∂w (``linearized``); ``identity`` the identity of w's size."""

    identity: np.ndarray

    def __call__(self, w: np.ndarray) -> np.ndarray: ...

    def linearized(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


class VectorFields(Protocol):
    """The vector fields of K runs: f and ∂f/∂w of w (k, size) for the runs ``rows``, (k,) indices
    of the K. A run whose evaluation raised is in ``raised`` (run → what it raised), its row NaN."""

    identity: np.ndarray
    raised: dict[int, str]

    def __call__(self, w: np.ndarray, rows: np.ndarray) -> np.ndarray: ...

    def linearized(self, w: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


def step_factor(ratio: float) -> float:
    """The next step over this one for an error ``ratio`` (max_i |error_i| / tolerance_i): 0.9 ρ^(−1/4),
    at most 5 (also for a zero error) and at least 1/5 (also for an error that is not finite, NaN
    included: Python's min and max keep their first argument against a NaN)."""
    return 5.0 if ratio == 0 else min(5.0, max(0.2, 0.9 * ratio**-0.25))


def _rosenbrock_step(
    ode: VectorField, w: np.ndarray, f: np.ndarray, J: np.ndarray, h: float, stages: np.ndarray
) -> np.ndarray:
    """One step of length h from w (f = f(w), J = ∂f/∂w there): its four stages U_i, solved into
    ``stages`` with one LU factorisation, and the rows Σ m_i U_i (the step) and Σ e_i U_i (its error)."""
    lu, pivots, _ = lapack.dgetrf(ode.identity * (1.0 / (_GAMMA * h)) - J)
    c = _C34 * (1.0 / h)
    U1 = stages[0] = lapack.dgetrs(lu, pivots, f)[0]
    stages[1] = lapack.dgetrs(lu, pivots, ode(w + _A21 * U1) + (_C21 / h) * U1)[0]
    f3 = ode(w + _A3.dot(stages[:2]))
    stages[2] = lapack.dgetrs(lu, pivots, f3 + c[0, :2].dot(stages[:2]))[0]
    stages[3] = lapack.dgetrs(lu, pivots, f3 + c[1].dot(stages[:3]))[0]
    return _SOLUTION_AND_ERROR.dot(stages)


def integrate(
    ode: VectorField,
    w: np.ndarray,
    linearized: tuple[np.ndarray, np.ndarray],
    span: float,
    h: float,
    rtol: float,
    atol: float,
    size: np.ndarray,
) -> tuple[np.ndarray, float]:
    """w(t + span) for the autonomous dw/dt = f(w) of ``ode``, given f(w) and ∂f/∂w (``linearized``),
    and the step to try next, from a first step h, by the Rosenbrock method above with step-size control.

    Each step solves (I/(γh) − J) U_i = f(w + Σ_{j<i} a_ij U_j) + Σ_{j<i} (c_ij/h) U_j, i = 1 … 4, with
    J = ∂f/∂w at w (a₄ⱼ = a₃ⱼ), and takes w + Σ m_i U_i; Σ e_i U_i, its difference from the embedded
    third-order solution, estimates its error. A step is kept when every |error_i| ≤ atol + rtol s_i,
    s_i the largest |w_i| so far (``size``, updated in place): relative to the size each component has
    had, not to its current value, which crosses zero. With ρ = max_i |error_i| / (atol + rtol s_i),
    the step proposed next is 0.9 ρ^(−1/4) h, within h/5 … 5 h (``step_factor``).

    The steps left in the span are of equal length, as many as the proposed step needs, rather than
    proposed steps and a short last one: the short step's small error proposes a first step for the
    next sample that is often too long and rejected, while equal steps, each somewhat shorter than
    proposed, seldom are (in ``bench/estimator_step.py``: 2.45 attempts for 2.0 kept steps per sample
    with a short last step, 2.08 for 1.95 with equal steps).

    I/(γh) − J is factorised once per step (LAPACK's LU) and each stage solved with its factors: at
    this size numpy's inv and solve cost several times more, in their checks, than the arithmetic.
    A singular matrix gives inf or NaN stages, which the error test rejects.
    """
    t = 0.0
    f, J = linearized
    stages = np.empty((4, w.size))
    while True:
        remaining = span - t
        h = remaining / max(1, math.ceil(remaining / h - 1e-9))  # (− 1e-9: no extra step for a rounding error)
        step_and_error = _rosenbrock_step(ode, w, f, J, h, stages)
        w_new = w + step_and_error[0]
        ratios = [
            abs(e) / (atol + rtol * max(s, abs(v)))
            for e, s, v in zip(step_and_error[1].tolist(), size.tolist(), w_new.tolist())
        ]
        ratio = math.nan if math.isnan(sum(ratios)) else max(ratios)  # max() would pass over a NaN
        factor = step_factor(ratio)
        if ratio <= 1.0:
            t, w = t + h, w_new
            np.maximum(size, np.abs(w), out=size)
            if t >= span * (1 - 1e-12):
                return w, h * factor
            f, J = ode.linearized(w)
        h *= factor
        if h < 1e-12 * span:
            raise FloatingPointError(_CANNOT)


def _rosenbrock_steps(
    ode: VectorFields, rows: np.ndarray, w: np.ndarray, f: np.ndarray, J: np.ndarray, h: np.ndarray
) -> np.ndarray:
    """``_rosenbrock_step`` of the runs ``rows`` (w, f (k, size), J (k, size, size), h (k,)): (k, 2, size).

    The stages' linear combinations are NumPy's stacked products, per run the kernel of the one-run
    ``dot``; the LU factorisation and the solves are the one-run LAPACK calls, run by run: NumPy's
    stacked ``solve`` is another build of LAPACK (its own OpenBLAS), which need not round alike."""
    # each matrix stored by columns (LAPACK's order), so that dgetrf factorises it in place, uncopied
    columns = (ode.identity * (1.0 / (_GAMMA * h))[:, None, None] - J).transpose(0, 2, 1).copy()
    factors = [lapack.dgetrf(M.T, overwrite_a=True)[:2] for M in columns]
    c = _C34 * (1.0 / h)[:, None, None]
    stages = np.empty((len(w), 4, w.shape[1]))

    def solve(into: int, rhs: np.ndarray) -> np.ndarray:
        """Stage ``into`` of each run from its right-hand side, solved in place (dgetrs' overwrite_b)."""
        stages[:, into] = rhs
        for stage, (lu, pivots) in zip(stages[:, into], factors):
            lapack.dgetrs(lu, pivots, stage, overwrite_b=True)
        return stages[:, into]

    U1 = solve(0, f)
    solve(1, ode(w + _A21 * U1, rows) + (_C21 / h)[:, None] * U1)
    f3 = ode(w + np.matmul(_A3, stages[:, :2]), rows)
    solve(2, f3 + np.matmul(c[:, None, 0, :2], stages[:, :2])[:, 0])
    solve(3, f3 + np.matmul(c[:, None, 1], stages[:, :3])[:, 0])
    return np.matmul(_SOLUTION_AND_ERROR, stages)


def integrate_runs(
    ode: VectorFields,
    rows: np.ndarray,
    w: np.ndarray,
    linearized: tuple[np.ndarray, np.ndarray],
    span: float,
    h: np.ndarray,
    rtol: float,
    atol: float,
    size: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, dict[int, str]]:
    """``integrate`` for the runs ``rows`` (k,) of K: w (k, size) with f and ∂f/∂w there, each run's
    first step h (k,), ``size`` (K, size) updated in place at ``rows``; returns w(t + span) and the
    steps to try next, (k, size) and (k,), and the runs that raised (run → what), their rows NaN.

    The runs make their attempts together, each with its own step, error test and decision, a run
    done with the span sitting out while the others go on; the arithmetic is ``integrate``'s in its
    order (the ratio's maximum NaN wherever a term is, as its sum tells; its ``step_factor``)."""
    w_end, h_end = np.full_like(w, np.nan), np.full(len(rows), np.nan)
    failed: dict[int, str] = {}
    at = np.arange(len(rows))  # the positions in rows (and in w_end, h_end) of the runs under way
    t, (f, J), h = np.zeros(len(rows)), linearized, h.astype(float)
    while at.size:
        if ode.raised and not (keep := _keep(ode, rows[at], failed)).all():
            at, t, w, f, J, h = at[keep], t[keep], w[keep], f[keep], J[keep], h[keep]
            continue
        runs, remaining = rows[at], span - t
        h = remaining / np.maximum(1.0, np.ceil(remaining / h - 1e-9))
        step_and_error = _rosenbrock_steps(ode, runs, w, f, J, h)
        w_new = w + step_and_error[:, 0]
        magnitude, scale = np.abs(w_new), size[runs]
        tolerance = atol + rtol * np.where(magnitude > scale, magnitude, scale)  # Python's max(s, |v|)
        ratio = (np.abs(step_and_error[:, 1]) / tolerance).max(axis=1)
        kept = ratio <= 1.0
        if kept.all():
            t, w = t + h, w_new
            size[runs] = np.maximum(scale, magnitude)
        else:
            t, w = np.where(kept, t + h, t), np.where(kept[:, None], w_new, w)
            size[runs[kept]] = np.maximum(scale[kept], magnitude[kept])
        h = h * np.array([step_factor(r) for r in ratio.tolist()])
        done = kept & (t >= span * (1 - 1e-12))
        if done.any():
            w_end[at[done]], h_end[at[done]] = w[done], h[done]
            if done.all():
                break
        again = kept & ~done
        if again.all():
            f, J = ode.linearized(w, runs)
        elif again.any():
            f, J = f.copy(), J.copy()
            f[again], J[again] = ode.linearized(w[again], runs[again])
        going = ~done & ~(h < 1e-12 * span)
        for run in runs[~done & ~going].tolist():  # (what raised first, if anything did)
            failed[run] = ode.raised.get(run, f"FloatingPointError: {_CANNOT}")
        if not going.all():
            at, t, w, f, J, h = at[going], t[going], w[going], f[going], J[going], h[going]
    return w_end, h_end, failed


def _keep(ode: VectorFields, runs: np.ndarray, failed: dict[int, str]) -> np.ndarray:
    """Which of ``runs`` go on: those whose evaluation raised are moved to ``failed``."""
    keep = np.array([r not in ode.raised for r in runs.tolist()], dtype=bool)
    for r in runs[~keep].tolist():
        failed[r] = ode.raised[r]
    return keep
