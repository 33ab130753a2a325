"""Which sensor gains changed, identified by the gain test (ours: γ̂ changes only on evidence;
docs/three-tank.md, "The gain test"): the model window's consistency equations (50), whitened by
the readings' noise, as a χ² test of the current gains and of the hypotheses of what changed, over
the last N samples. The hypotheses are searched in ``estimators.gain_hypotheses``, over the stack
of a window's systems (the whole window and its splits), or of every searching run's in a batch.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from estimators.batched import mv
from estimators.gain_hypotheses import GainHypothesis, SystemStack, chi2_quantile, stacked_hypotheses
from estimators.model_window import Projection, complement_projection, reduced_system, reduced_systems, stacked_window


@dataclass(frozen=True)
class GainTestWindow:
    """The consistency equations (50) of the last L samples, L = ``min_window`` … N, linked by the
    plant model (1) as in ``ModelWindow``, but whitened by the readings' noise level; built once by
    ``gain_test_window``, used every tick by ``window_system``.

    With white measurement noise n_j(k) ~ N(0, σ_j²) added before the gain, y = Δ(γ)(C_y x_p + n) + F b
    (the testbed adds noise first, then the faults), sensor j's equation

        β_j y_j(k) − d_j − C_y⁽ʲ⁾ x_p(k) = n_j(k),    β_j = 1/γ_j, d_j = β_j F⁽ʲ⁾ b,

    divided by σ_j, has a unit normal error. Projecting off the nuisance unknowns θ = (d, x_p(0),
    v(0 … L−2)) leaves the residual P⊥ D (Y β − r) = P⊥ e at the true β, e ~ N(0, I): its squared
    norm is χ² with L m − rank(Z_L) degrees of freedom, whatever the state, the inputs, the unknown
    input and the bias. The sub-window of the last L samples is the top-left block of the N-sample
    window (the model is time-invariant), so one Z serves every L.
    """

    weight: np.ndarray
    """D = 1/σ_j per sensor, shape (m,)."""
    nuisance: np.ndarray
    """Z over N samples, whitened, shape (N, m, m + n + (N − 1) n_v)."""
    columns: tuple[int, ...]
    """Per L = min_window … N: the columns of Z that the last L samples involve, m + n + (L − 1) n_v."""
    bases: tuple[np.ndarray, ...]
    """Per L = min_window … N: an orthonormal basis of range(Z_L), shape (L m, rank Z_L)."""
    forced: np.ndarray
    """Σ_{i<k} C_y A^(k−1−i) B by sample and input, whitened, shape (N, m, N − 1, n_u)."""
    min_window: int
    """The shortest sub-window that may identify the gains after a change."""
    projection: Projection
    """W' of the whole window, the whitened equations of the N samples that the nuisance unknowns
    cannot satisfy: the test of every tick, on the whole window with nothing missing, needs no more."""
    jumps: dict[tuple[int, int], np.ndarray] = field(default_factory=dict, compare=False, repr=False)
    """By (L, c): an orthonormal basis of the offsets' jumps at sample c of L samples with nothing
    missing, projected off range(Z_L), as ``window_system`` computes it (it depends on neither the
    readings nor the inputs): filled as the splits are first tested."""

    @property
    def window(self) -> int:
        return int(self.forced.shape[0])


def gain_test_window(
    A: np.ndarray, B: np.ndarray, E: np.ndarray, C: np.ndarray, noise_std: np.ndarray, N: int, min_window: int
) -> GainTestWindow:
    """The ``GainTestWindow`` of x⁺ = A x + B u + E v, y = Δ(γ)(C x + n) + F b, n_j ~ N(0, σ_j²).

    Shapes: A (n, n), B (n, n_u), E (n, n_v), C (m, n), noise_std (m,); 2 ≤ min_window ≤ N.
    """
    n, m, nv = A.shape[0], C.shape[0], E.shape[1]
    Z, forced = stacked_window(A, B, E, C, N)
    weight = 1.0 / np.asarray(noise_std, dtype=float)
    Z *= weight[None, :, None]
    forced *= weight[None, :, None, None]
    columns = tuple(m + n + (L - 1) * nv for L in range(min_window, N + 1))
    bases = tuple(
        _range_basis(Z[:L, :, :c].reshape(L * m, c)) for L, c in zip(range(min_window, N + 1), columns, strict=True)
    )
    return GainTestWindow(weight, Z, columns, bases, forced, min_window, complement_projection(Z, forced))


def _range_basis(Z: np.ndarray) -> np.ndarray:
    """An orthonormal basis of range(Z), as columns."""
    U, sv, _ = np.linalg.svd(Z, full_matrices=False)
    rank = int(np.sum(sv > sv[0] * 1e-10)) if sv.size and sv[0] > 0 else 0
    return U[:, :rank]


class WindowSystem(NamedTuple):
    """A window's whitened equations with the nuisance unknowns projected out, in the reduced form
    of least squares: T(β) = ‖factor β − rotated‖² + rest, χ²(dof) at the true β."""

    factor: np.ndarray
    """R of the QR factorization of the projected regressor P⊥ D Y, shape (m, m)."""
    rotated: np.ndarray
    """Qᵀ P⊥ D r, shape (m,): the projected target in the regressor's column space."""
    rest: float
    """The part of ‖P⊥ D r‖² no β can explain."""
    dof: int
    """Equations less the rank of the nuisance columns: the residual's degrees of freedom at the
    true β."""


class WindowEquations(NamedTuple):
    """A window's whitened equations before any projection (``window_equations``)."""

    Y: np.ndarray
    """D Y, the readings as the gains' regressor, shape (L m, m); 0 where one is missing."""
    r: np.ndarray
    """D r, the inputs' forced response, shape (L m,)."""
    kept: np.ndarray
    """The equations whose reading arrived, shape (L m,)."""


def window_equations(window: GainTestWindow, y: np.ndarray, u: np.ndarray) -> WindowEquations:
    """The whitened equations of the last L = len(y) samples, y (L, m) and u (L, n_u) as in
    ``window_system``: what every split of one window shares."""
    L, m = y.shape
    Y = np.zeros((L * m, m))
    Y[np.arange(L * m), np.tile(np.arange(m), L)] = (np.where(np.isnan(y), 0.0, y) * window.weight).ravel()
    r = np.einsum("kjil,il->kj", window.forced[:L, :, : L - 1], u[:-1]).ravel()
    return WindowEquations(Y, r, ~np.isnan(y).ravel())


def window_system(
    window: GainTestWindow,
    y: np.ndarray,
    u: np.ndarray,
    change: int | None = None,
    before: np.ndarray | None = None,
    equations: WindowEquations | None = None,
) -> WindowSystem:
    """The system of the last L = len(y) samples, min_window ≤ L ≤ N: readings y (L, m), NaN where
    one did not arrive (its equation is dropped), and inputs u (L, n_u), u(k) held from k to k + 1.

    With ``change`` = c (0 < c < L), the gains change at sample c: samples k < c have the known
    β = ``before`` (their terms move to the target), and the regressor holds only samples k ≥ c.
    Each sensor's offset d_j may jump at c as well (a bias step, or d_j = β_j F⁽ʲ⁾ b with a new
    β_j): m more nuisance columns, projected out with the others. ``equations``: the window's
    ``window_equations``, where the caller has them (it tests several splits of one window)."""
    L, m = y.shape
    if change is None and L == window.window and not np.isnan(y).any():
        reduced = reduced_system(window.projection, y * window.weight, u)
        dof = window.projection.forced.shape[0]  # the equations left: L m − rank(Z_L)
        return WindowSystem(reduced[:m, :m], reduced[:m, m], float(reduced[m, m]) ** 2, dof)
    index = L - window.min_window
    Y, r, kept = window_equations(window, y, u) if equations is None else equations
    rows = np.arange(L * m)
    if change is not None:
        assert before is not None and 0 < change < L
        after = np.repeat(np.arange(L), m) >= change
        r = r - np.where(after, 0.0, Y @ before)
        Y = Y.copy()
        Y[~after] = 0.0
    if kept.all():
        Q = window.bases[index]
    else:  # the range of the nuisance columns within the equations that are left
        Q = _range_basis(window.nuisance[:L, :, : window.columns[index]].reshape(L * m, -1)[kept])
        Y, r, rows = Y[kept], r[kept], rows[kept]
    Y = Y - Q @ (Q.T @ Y)
    r = r - Q @ (Q.T @ r)
    dof = len(r) - Q.shape[1]
    if change is not None:
        G = _jumps(window, L, change, Q, rows, bool(kept.all()))
        Y = Y - G @ (G.T @ Y)
        r = r - G @ (G.T @ r)
        dof -= G.shape[1]
    basis, factor = np.linalg.qr(Y)
    rotated = basis.T @ r
    return WindowSystem(factor, rotated, float(max(r @ r - rotated @ rotated, 0.0)), int(dof))


def _jumps(window: GainTestWindow, L: int, change: int, Q: np.ndarray, rows: np.ndarray, cached: bool) -> np.ndarray:
    """An orthonormal basis of the offsets' jumps at sample ``change`` of the last L samples (the
    equations ``rows`` of them that are left), projected off Q, the nuisance columns' range; kept in
    ``window.jumps`` where every equation is (``cached``)."""
    G = window.jumps.get((L, change)) if cached else None
    if G is None:
        m = window.weight.size
        J = np.zeros((len(rows), m))  # the offsets' jumps, whitened
        jumped = rows // m >= change
        J[jumped, rows[jumped] % m] = window.weight[rows[jumped] % m]
        G = _range_basis(J - Q @ (Q.T @ J))
        if cached:
            window.jumps[L, change] = G
    return G


def window_splits(window: GainTestWindow, y: np.ndarray, u: np.ndarray, before: np.ndarray) -> list[WindowSystem]:
    """``window_system`` of the whole window (y (N, m), u (N, n_u)) with the gains changing at each
    sample c = N − L, L = min_window … N − 1, in that order, from β = ``before``: on stacks
    (``split_systems``) where every reading arrived, split by split where one did not."""
    equations = window_equations(window, y, u)
    if equations.kept.all():
        return split_systems(window, [equations], before[None])[0]
    N = window.window
    return [
        window_system(window, y, u, change=N - L, before=before, equations=equations)
        for L in range(window.min_window, N)
    ]


def split_systems(
    window: GainTestWindow, equations: Sequence[WindowEquations], befores: np.ndarray
) -> list[list[WindowSystem]]:
    """``window_splits`` of K whole windows with every reading (a batch's runs: their equations, and
    their β before the change (K, m)), by run, then split: every split of every run projected and
    factorised in one stacked product or QR per step (each matrix by the BLAS or LAPACK call of its
    ``window_system``, so each system is that one bit for bit); only the offsets' jumps, whose basis
    depends on the split, split by split over the runs."""
    N, m = window.window, window.weight.size
    changes = range(N - window.min_window, 0, -1)  # c = N − L for L = min_window … N − 1
    Q, rows = window.bases[N - window.min_window], np.arange(N * m)
    Y, r = np.stack([e.Y for e in equations]), np.stack([e.r for e in equations])
    after = (rows // m)[None, :] >= np.array(changes)[:, None]  # (splits, N m): the samples after the change
    Ys = np.where(after[:, None, :, None], Y, 0.0)  # (splits, K, N m, m)
    rs = r - np.where(after[:, None, :], 0.0, mv(Y, befores))
    Ys = Ys - Q @ (Q.T @ Ys)
    rs = rs - mv(Q, mv(Q.T, rs))
    dof = []
    for s, change in enumerate(changes):
        G = _jumps(window, N, change, Q, rows, True)
        Ys[s] = Ys[s] - G @ (G.T @ Ys[s])
        rs[s] = rs[s] - mv(G, mv(G.T, rs[s]))
        dof.append(N * m - Q.shape[1] - G.shape[1])
    basis, factor = np.linalg.qr(Ys)
    rotated = mv(np.swapaxes(basis, -1, -2), rs)
    rest = _squares(rs) - _squares(rotated)
    return [
        [WindowSystem(factor[s, k], rotated[s, k], float(max(rest[s, k], 0.0)), dof[s]) for s in range(len(dof))]
        for k in range(len(equations))
    ]


def _squares(vectors: np.ndarray) -> np.ndarray:
    """v @ v of each vector (…, n) by the dot kernel of the single product."""
    return np.matmul(vectors[..., None, :], vectors[..., None])[..., 0, 0]


def chi2_statistic(system: WindowSystem, beta: np.ndarray) -> float:
    """T(β) = ‖P⊥ D (Y β − r)‖², χ²(dof) when β is the true 1/γ."""
    residual = system.factor @ beta - system.rotated
    return float(residual @ residual) + system.rest


def gain_standard_errors(system: WindowSystem) -> np.ndarray:
    """The standard error of each β̂_j fitted alone (the others given), 1/‖P⊥ D Y_j‖: how well the
    window resolves a change of that sensor's gain (γ̂ = 1/β̂ has about the same near γ = 1)."""
    factor = system.factor
    norms = np.sqrt(np.add.reduce(factor * factor, axis=0))  # np.linalg.norm(axis=0)'s arithmetic, without its checks
    return np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), np.inf)


def standard_errors(factors: np.ndarray) -> np.ndarray:
    """``gain_standard_errors`` of K windows' factors (K, m, m), each run's bit for bit."""
    norms = np.sqrt(np.add.reduce(factors * factors, axis=1))  # np.linalg.norm(axis=0)'s arithmetic, without its checks
    return np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), np.inf)


def window_systems(window: GainTestWindow, y: np.ndarray, u: np.ndarray) -> list[WindowSystem]:
    """``window_system`` of K whole windows with every reading (a batch's runs: y (K, N, m), u (K, N,
    n_u)), each run's bit for bit."""
    m = y.shape[2]
    reduced = reduced_systems(window.projection, y * window.weight, u)
    dof = window.projection.forced.shape[0]
    return [WindowSystem(r[:m, :m], r[:m, m], float(r[m, m]) ** 2, dof) for r in reduced]


def window_tests(
    window: GainTestWindow, y: np.ndarray, u: np.ndarray, gamma: np.ndarray, alpha: float, se_tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """What ``decide_gains`` first computes, for K whole windows with every reading (a batch's runs:
    y (K, N, m), u (K, N, n_u), the previous γ̂ (K, m)): the statistic of γ̂ over its threshold and the
    excitation, each (K,), each run's bit for bit; a run whose statistic is ≤ 1 keeps γ̂
    (``consistent``) where no change is being identified."""
    m = y.shape[2]
    reduced = reduced_systems(window.projection, y * window.weight, u)
    factor, rotated = reduced[:, :m, :m], reduced[:, :m, m]
    rest = np.array([float(v) ** 2 for v in reduced[:, m, m]])
    residual = np.matmul(factor, (1.0 / gamma)[..., None])[..., 0] - rotated  # chi2_statistic's arithmetic
    statistic = np.matmul(residual[:, None, :], residual[:, :, None])[:, 0, 0] + rest
    threshold = chi2_quantile(alpha, window.projection.forced.shape[0])
    return statistic / threshold, se_tol / np.max(standard_errors(factor), axis=1)


def gain_hypotheses(
    system: WindowSystem, alpha: float, lower: np.ndarray, upper: np.ndarray, previous: np.ndarray, samples: int
) -> list[GainHypothesis]:
    """The hypotheses with the fewest fitted gains that the window does not reject at level α
    (``stacked_hypotheses`` of this one system); none if it rejects every one."""
    return window_hypotheses([system], [samples], previous, alpha, lower, upper)


def window_hypotheses(
    systems: Sequence[WindowSystem],
    samples: Sequence[int],
    previous: np.ndarray,
    alpha: float,
    lower: np.ndarray,
    upper: np.ndarray,
) -> list[GainHypothesis]:
    """The accepted hypotheses of each of ``systems`` (one window's, with the changes they place
    ``samples`` samples ago and β = ``previous`` before), in one stacked search, system after system."""
    return [h for found in searched_windows([(systems, samples, previous)], alpha, lower, upper) for h in found]


def search_systems(
    window: GainTestWindow, full: WindowSystem, splits: Sequence[WindowSystem]
) -> tuple[list[WindowSystem], list[int]]:
    """What ``decide_gains`` searches: the whole window's system, then its splits' (none, or one per
    L = min_window … N − 1), with the samples since the change each places (N for the whole window)."""
    N = window.window
    return [full, *splits], [N, *range(window.min_window, window.min_window + len(splits))]


def searched_windows(
    searches: Sequence[tuple[Sequence[WindowSystem], Sequence[int], np.ndarray]],
    alpha: float,
    lower: np.ndarray,
    upper: np.ndarray,
) -> list[list[GainHypothesis]]:
    """``window_hypotheses`` of several windows (a batch's runs: each its systems, their samples and
    its β before the change) in one stacked search (``stacked_hypotheses``), by window."""
    systems = [system for found, _, _ in searches for system in found]
    stack = SystemStack(
        np.stack([s.factor for s in systems]),
        np.stack([s.rotated for s in systems]),
        np.array([s.rest for s in systems], dtype=float),
        np.array([s.dof for s in systems]),
        np.concatenate([np.broadcast_to(before, (len(found), before.size)) for found, _, before in searches]),
        [n for _, counts, _ in searches for n in counts],
    )
    found = stacked_hypotheses(stack, alpha, lower, upper)
    ends = np.cumsum([0] + [len(systems) for systems, _, _ in searches]).tolist()
    return [[h for one in found[a:b] for h in one] for a, b in itertools.pairwise(ends)]


class GainDecision(NamedTuple):
    """What the gain test decided at one tick."""

    gamma: np.ndarray
    """γ̂ after the tick (the previous one unless new gains were identified)."""
    verdict: str
    """``consistent``: the window accepts the previous γ̂, which is kept; ``identified``: it rejects
    it and one hypothesis explains the window, with the change ``samples`` samples ago (``samples``
    = N: before the window); ``pending``: it rejects it, but first did so fewer than min_window
    samples ago, too few to tell what changed (γ̂ kept); ``ambiguous``: several hypotheses explain
    it, or the only one does not resolve its gains to ``se_tol`` (γ̂ kept); ``inconsistent``: none
    explains it (γ̂ kept)."""
    statistic: float
    """T of the previous γ̂ on the window over the (1 − α) quantile of χ²(dof) (≤ 1: accepted)."""
    excitation: float
    """se_tol over the largest standard error of a gain on the window (≥ 1: it resolves every gain
    to se_tol)."""
    samples: int
    """The samples since the change the decision places (N: none in the window)."""


def decide_gains(
    window: GainTestWindow,
    y: np.ndarray,
    u: np.ndarray,
    gamma: np.ndarray,
    alpha: float,
    lower: np.ndarray,
    upper: np.ndarray,
    se_tol: float,
    reference: np.ndarray | None = None,
    since: int | None = None,
    searched: Sequence[GainHypothesis] | None = None,
) -> GainDecision:
    """γ̂ changes only on evidence (docs/three-tank.md, "The gain test").

    Without ``reference`` the window of the last N samples first tests the previous γ̂: if T(1/γ̂)
    is within the (1 − α) quantile of χ²(dof), γ̂ is kept. Otherwise the gains changed, from
    ``reference`` (the γ̂ before the change; default: the previous γ̂), and the hypotheses are:

    - the change is before the window: constant gains over it (``gain_hypotheses``);
    - it is at sample c of the window, L = N − c ≥ min_window samples ago: the known gains before c,
      the hypothesis after it, every offset free to jump at c;
    - only if none of these is accepted (two changes in the window, e.g. a bias step, then a gain):
      the last samples alone (``_latest_identification``), at most ``since`` of them (the samples
      since the window first rejected the gains before the change): none reaches back across it.

    Nothing is identified until the window has rejected the gains before the change for min_window
    samples (``since``): fewer are explained as well by hypotheses that place the change earlier.

    Among the accepted hypotheses with the fewest fitted gains, the likeliest is taken if they all
    agree on what changed and it resolves its gains to ``se_tol`` (``_unambiguous``), else ``ambiguous``.
    y (N, m), u (N, n_u) as in ``window_system``; gamma: the previous γ̂; lower, upper: the box Γ;
    ``searched``: the hypotheses that the whole window and its splits accept (``searched_windows``
    of ``search_systems``), where the caller searched them with other runs'."""
    N = window.window
    full = window_system(window, y, u)
    threshold = chi2_quantile(alpha, full.dof)
    statistic = chi2_statistic(full, 1.0 / gamma) / threshold
    excitation = se_tol / float(np.max(gain_standard_errors(full)))
    if reference is None:
        if statistic <= 1.0:
            return GainDecision(gamma, "consistent", statistic, excitation, N)
        reference = gamma
    since = 1 if since is None else since
    if since < window.min_window:
        return GainDecision(gamma, "pending", statistic, excitation, N)
    previous, beta_lower, beta_upper = 1.0 / reference, 1.0 / upper, 1.0 / lower
    if searched is None:
        splits = window_splits(window, y, u, previous) if since < N else []
        searched = window_hypotheses(*search_systems(window, full, splits), previous, alpha, beta_lower, beta_upper)
    accepted = list(searched)
    if accepted:
        best = _unambiguous(accepted, N, se_tol)
        if best is None:
            return GainDecision(gamma, "ambiguous", statistic, excitation, N)
        return GainDecision(1.0 / best.beta, "identified", statistic, excitation, best.samples)
    found, explained = _latest_identification(window, y, u, alpha, beta_lower, beta_upper, previous, since, se_tol)
    if found is not None:
        return GainDecision(1.0 / found.beta, "identified", statistic, excitation, found.samples)
    return GainDecision(gamma, "ambiguous" if explained else "inconsistent", statistic, excitation, N)


def _unambiguous(accepted: list[GainHypothesis], N: int, se_tol: float) -> GainHypothesis | None:
    """Among the accepted hypotheses with the fewest fitted gains, the change before the window if
    that explains it (m fewer unknowns), else the likeliest split; None if they disagree on which
    gains changed (and which returned to 1) or it does not resolve its gains to ``se_tol``."""
    fewest = min(len(h.free) for h in accepted)
    accepted = [h for h in accepted if len(h.free) == fewest]
    before = [h for h in accepted if h.samples == N]
    best = max(before or accepted, key=lambda h: h.p_value)
    if len({h.kind for h in accepted}) > 1 or best.standard_error > se_tol:
        return None
    return best


def _latest_identification(
    window: GainTestWindow,
    y: np.ndarray,
    u: np.ndarray,
    alpha: float,
    lower: np.ndarray,
    upper: np.ndarray,
    previous: np.ndarray,
    since: int,
    se_tol: float,
) -> tuple[GainHypothesis | None, bool]:
    """The last L samples alone, L = min_window, min_window + 1, … up to the first L that no
    hypothesis explains, and at most ``since``: the longest that identifies the gains (or None), and
    whether any was explained. ``lower`` and ``upper`` bound β."""
    N = window.window
    found, explained = None, False
    for L in range(window.min_window, min(N - 1, since) + 1):
        hypotheses = gain_hypotheses(window_system(window, y[N - L :], u[N - L :]), alpha, lower, upper, previous, L)
        if not hypotheses:
            break
        explained = True
        best = max(hypotheses, key=lambda h: h.p_value)
        if len({h.kind for h in hypotheses}) == 1 and best.standard_error <= se_tol:
            found = best
    return found, explained
