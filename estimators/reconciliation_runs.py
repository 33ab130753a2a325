"""The arithmetic of the reconciliators' on-line phase (IJC 2018) over the K runs of a batch
(``estimators.reconciliation_batch``): the UIO step (10), the LPV gain, the gain estimate (53), each
with a leading run axis, and each run's numbers bit for bit what the single step computes
(``estimators.reconciliation``) by the same operations: stacked ``matmul`` (``estimators.batched.mv``:
one BLAS call per run, the single call's, on a matrix held in the single run's memory order),
elementwise operations, ``einsum`` sums per run, LAPACK run by run. The single step keeps its own
one-run forms (these cost it twice its time at K = 1, in NumPy's calls);
tests/test_batched_reconciliation.py holds the two together.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.linalg import lapack

from estimators.batched import mv


class Uio(NamedTuple):
    """The UIO's matrices at each run's γ̂ (eq. (11)–(14)): Q (K, n + q, m), T (K, n + q, n + q),
    C̄ (K, m, n + q) and the gain L (K, n + q, m)."""

    Q: np.ndarray
    T: np.ndarray
    Cbar: np.ndarray
    L: np.ndarray

    def rows(self, rows: np.ndarray | slice) -> Uio:
        return Uio(*(matrix[rows] for matrix in self))


def matrices(runs: int, shape: tuple[int, ...], fortran: bool = False) -> np.ndarray:
    """An empty stack of K matrices (K, a, b) whose rows are each C- or (``fortran``) F-contiguous: a
    product rounds by its operands' memory order (BLAS runs another kernel on a transposed matrix),
    so each run's matrix is held in the order the single run has it."""
    if fortran:
        return np.empty((runs, shape[1], shape[0])).transpose(0, 2, 1)
    return np.empty((runs, *shape))


def scheduled_gains(
    rho: np.ndarray,
    G_vertices: np.ndarray,
    Y_vertices: np.ndarray,
    gammas: np.ndarray,
    failed: dict[int, str] | None = None,
) -> np.ndarray:
    """``LpvUioReconciliator.gain`` of K runs: L(ρ̂) = G(ρ̂)⁻¹ Y(ρ̂) with G(ρ̂) = Σ ρ_i G_i, Y(ρ̂) = Σ ρ_i Y_i
    at each run's coordinates ρ̂ (K, l), the sums stacked, LAPACK's solve run by run; (K, n + q, m),
    each as LAPACK returns it (Fortran order). With ``failed``, a run whose G(ρ̂) is singular is
    recorded there and left NaN (and a run it holds already is not solved); without, it raises."""
    l, nx, m = Y_vertices.shape
    G = np.matmul(rho[:, None, :], G_vertices.reshape(l, nx * nx))[:, 0].reshape(-1, nx, nx)
    Y = np.matmul(rho[:, None, :], Y_vertices.reshape(l, nx * m))[:, 0].reshape(-1, nx, m)
    gains = matrices(len(rho), (nx, m), fortran=True)
    gains[...] = np.nan
    for k, gamma in enumerate(gammas):
        if failed is not None and k in failed:
            continue
        lu, pivots, L, info = lapack.dgesv(G[k], Y[k])
        if info == 0:
            gains[k] = L
            continue
        why = f"G(ρ̂) is singular at γ̂ = {gamma.tolist()} (Theorem 1 makes it invertible)"
        if failed is None:
            raise np.linalg.LinAlgError(why)
        failed[k] = f"LinAlgError: {why}"
    return gains


def uio_steps(
    uio: Uio,
    Abar: np.ndarray,
    Bbar: np.ndarray,
    x_bar0: np.ndarray,
    previous: tuple[np.ndarray, np.ndarray, np.ndarray],
    fresh: np.ndarray,
    y: np.ndarray,
    coast: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One step of the UIO (10) in K runs: x̂(t) = T x̄(t) + L (y(t−1) − C̄ x̂(t−1)) + Q y(t), with
    x̄(t) = Ā x̂(t−1) + B̄ u(t−1) from ``previous`` = (x̂(t−1), y(t−1), u(t−1)), each (K, ·); a run
    that is ``fresh`` (K,) starts from x̂₀ (x̂(t) = T x̂₀ + Q y(t), the UIO's own reconstruction). A
    reading that did not arrive (NaN in y (K, m)) is replaced by its prediction C̄ x̄(t); in a run
    that ``coast``s (K,) all are. Returns x̂(t) (K, n + q) and the readings used (K, m)."""
    x_hat, y_prev, u_prev = previous
    if fresh.all():
        prior, x_next = x_bar0, np.matmul(uio.T, x_bar0)
    else:
        prior = mv(Abar, x_hat) + mv(Bbar, u_prev)
        x_next = mv(uio.T, prior) + mv(uio.L, y_prev - mv(uio.Cbar, x_hat))  # eq. (10)
        if fresh.any():
            prior = np.where(fresh[:, None], x_bar0, prior)
            x_next = np.where(fresh[:, None], np.matmul(uio.T, x_bar0), x_next)
    replaced = np.isnan(y)
    if coast.any():
        replaced |= coast[:, None]
    used = np.where(replaced, mv(uio.Cbar, prior), y) if replaced.any() else y
    return x_next + mv(uio.Q, used), used


def paper_gains(
    ys: np.ndarray,
    xs: np.ndarray,
    bs: np.ndarray,
    C: np.ndarray,
    F: np.ndarray,
    gamma: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The QP (53) over K windows (51)–(52), ys (K, N, m), xs (K, N, n), bs (K, N, q): γ̂ (K, m) and
    the relative residual (K,) of each.

    φ(t) stacks X(t−i) = diag(C_y⁽ʲ⁾ x̂_p(t−i)), so φᵀφ is diagonal and (53) separates into one
    scalar problem per sensor, min Σ_i (r_ij − γ_j s_ij)² over γ̲ ≤ γ_j ≤ γ̄, with
    s_ij = C_y⁽ʲ⁾ x̂_p(t−i) and r_ij = y_j(t−i) − F⁽ʲ⁾ b̂(t−i); each is solved exactly by
    clipping its unconstrained minimizer. A sensor whose regressor column is zero (rank φ < m,
    condition (54)) keeps its previous estimate ``gamma`` (K, m).
    """
    s = np.matmul(xs, C.T)  # (K, N, m)
    r = ys - np.matmul(bs, F.T)
    energy = np.einsum("kij,kij->kj", s, s)
    gamma = np.divide(np.einsum("kij,kij->kj", r, s), energy, out=gamma.copy(), where=energy > 0.0)
    gamma = np.minimum(np.maximum(gamma, lower), upper)  # clipped to Γ
    misfit = r - gamma[:, None, :] * s
    size = np.einsum("kij,kij->k", r, r)
    with np.errstate(divide="ignore", invalid="ignore"):
        fit = np.where(size > 0, np.sqrt(np.einsum("kij,kij->k", misfit, misfit) / size), 0.0)
    return gamma, fit


def singular_values(matrices: np.ndarray) -> np.ndarray:
    """The singular values of each run's matrix (K, a, b), by LAPACK's dgesvd run by run (as
    np.linalg.svd, without its checks' cost every tick)."""
    return np.stack([lapack.dgesvd(matrix, compute_uv=0)[1] for matrix in matrices])


def excitations(sv: np.ndarray, rank: int, tolerance: float) -> np.ndarray:
    """σ_min/σ_max of each run's regressor (singular values (K, k)) that must have ``rank`` columns'
    worth of excitation; 0 where that ratio is below ``tolerance`` (the condition fails)."""
    if sv.shape[1] < rank:
        return np.zeros(len(sv))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(sv[:, 0] > 0, sv[:, -1] / sv[:, 0], 0.0)
    return np.where(ratio >= tolerance, ratio, 0.0)


def published_excitation(excitation: np.ndarray) -> np.ndarray:
    """The gain test's ``pe`` diagnostic of each run: se_tol over the largest standard error, ≥ 1 when
    the window resolves every gain, published up to 2, the channel's declared range (a well-excited
    window reads 2, not its exact margin); 0 below 1."""
    return np.where(excitation >= 1.0, np.minimum(excitation, 2.0), 0.0)
