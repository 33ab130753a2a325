"""The model window of the sensor-gain estimator (ours, beside IJC 2018's (50)–(53)): the
consistency equations (50) of a window of N samples with the plant model (1) as the link between
samples, solved for the gains by bounded least squares (docs/three-tank.md, "The model window").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from estimators.box_least_squares import box_least_squares, box_least_squares_runs
from estimators.stacked import singular_values, triangular_factors

_TINY = float(np.finfo(float).tiny)


class Projection(NamedTuple):
    """W' (R, N m), an orthonormal basis of the equations of a window of N samples that its nuisance
    unknowns cannot satisfy, in the two forms a tick needs."""

    by_sensor: np.ndarray
    """W'_j, the columns of W' that weigh sensor j's readings y_j(0 … N−1), shape (m, R, N)."""
    forced: np.ndarray
    """W' applied to the forced response, shape (R, (N − 1) n_u): times u(0 … N−2) stacked, W' r."""


def complement_projection(Z: np.ndarray, forced: np.ndarray) -> Projection:
    """The ``Projection`` onto the complement of range(Z) of a window's equations: Z (N, m, k), the
    nuisance columns; forced (N, m, N − 1, n_u), as ``stacked_window`` returns them (weighted)."""
    N, m = Z.shape[:2]
    return _projection(_complement(Z.reshape(N * m, -1)).reshape(-1, N, m), forced)


def _projection(W: np.ndarray, forced: np.ndarray) -> Projection:
    """The ``Projection`` of W' given as (R, N, m), with the forced response (N, m, N − 1, n_u)."""
    by_sensor = np.ascontiguousarray(W.transpose(2, 0, 1))
    return Projection(by_sensor, np.einsum("rkj,kjil->ril", W, forced).reshape(len(W), -1))


def reduced_system(projection: Projection, y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """R̃ (m + 1, m + 1), the triangular factor of the QR factorization of [W' Y, W' r], with
    Y = diag(y(k)) stacked: readings y (N, m), weighted, 0 where one is missing; inputs u (N, n_u).
    Its blocks R = R̃[:m, :m], c = R̃[:m, m] and ρ = R̃[m, m] hold all of the window's least squares in
    β: ‖W' Y β − W' r‖² = ‖R β − c‖² + ρ² for every β, and W' Y has the singular values and column
    norms of R."""
    m, rows = y.shape[1], projection.by_sensor.shape[1]
    columns = np.empty((m + 1, rows))  # [W' Y, W' r] column by column: the Fortran order LAPACK takes
    np.matmul(projection.by_sensor, y.T[:, :, None], out=columns[:m, :, None])  # W' Y: column j is W_j' y_j
    columns[m] = projection.forced.dot(u[:-1].ravel())  # W' r
    return triangular_factors(columns.T, overwrite=True)


def reduced_systems(projection: Projection, y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``reduced_system`` of K windows at once (a batch's runs): y (K, N, m), u (K, N, n_u) →
    (K, m + 1, m + 1), each run's bit for bit (the products stacked, one QR per run)."""
    runs, m, rows = y.shape[0], y.shape[2], projection.by_sensor.shape[1]
    columns = np.empty((runs, m + 1, rows))  # [W' Y, W' r] column by column: the Fortran order LAPACK takes
    np.matmul(projection.by_sensor, np.swapaxes(y, 1, 2)[..., None], out=columns[:, :m, :, None])  # W_j' y_j
    np.matmul(projection.forced, u[:, :-1].reshape(runs, -1, 1), out=columns[:, m, :, None])  # W' r
    return triangular_factors(np.swapaxes(columns, 1, 2), overwrite=True)


@dataclass(frozen=True)
class ModelWindow:
    """The consistency equations (50) over a window of N samples, with the plant model (1) as the
    link between samples; built once by ``model_window``, used every tick by ``window_gains``.

    Divide (2) by the gains, β_j = 1/γ_j: β_j y_j(k) − β_j F⁽ʲ⁾ b = C_y⁽ʲ⁾ x_p(k). With d_j = β_j F⁽ʲ⁾ b
    taken as a free offset per sensor, and x_p(k) = A^k x_p(0) + Σ_{i<k} A^(k−1−i) (B u(i) + E v(i))
    over the window k = 0 … N−1, every sample gives m equations linear in all the unknowns:

        Y(k) β − d − C_y A^k x_p(0) − Σ_{i<k} C_y A^(k−1−i) E v(i) = Σ_{i<k} C_y A^(k−1−i) B u(i),

    with Y(k) = diag(y(k)), each sensor's equations weighted by 1/‖C_y⁽ʲ⁾‖. The nuisance unknowns
    θ = (d, x_p(0), v(0), …, v(N−2)) enter through a fixed matrix Z, so β is the least-squares
    solution of W' Y β = W' r, where the columns of W are an orthonormal basis of the complement of
    range(Z).
    """

    nuisance: np.ndarray
    """Z, shape (N m, m + n + (N − 1) n_v): the columns of d, x_p(0) and v(0 … N−2), weighted."""
    response: np.ndarray
    """Σ_{i<k} C_y A^(k−1−i) B by sample and input, weighted, shape (N, m, N − 1, n_u)."""
    weight: np.ndarray
    """1/‖C_y⁽ʲ⁾‖ per sensor, shape (m,): each sensor's equations in units of the state, so that a
    sensor scaled up (10·h1) does not outweigh the others in the fit and in its residual."""
    projection: Projection
    """W', the (weighted) equations that the nuisance unknowns cannot satisfy."""


def _complement(Z: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the orthogonal complement of range(Z), as rows."""
    U, sv, _ = np.linalg.svd(Z, full_matrices=True)
    rank = int(np.sum(sv > sv[0] * 1e-10)) if sv.size and sv[0] > 0 else 0
    return U[:, rank:].T


def stacked_window(A: np.ndarray, B: np.ndarray, E: np.ndarray, C: np.ndarray, N: int) -> tuple[np.ndarray, np.ndarray]:
    """The N samples' equations of x⁺ = A x + B u + E v, y = C x + b, stacked: sample k reads
    0 = Z_k [b; x_0; v_0 … v_{N-2}] + y_k − Σ_{i<k} C A^{k-1-i} B u_i, with ``forced[k, :, i]`` =
    C A^{k-1-i} B. Shapes: Z (N, m, m + n + (N−1) n_v), forced (N, m, N−1, n_u)."""
    n, m, nv, nu = A.shape[0], C.shape[0], E.shape[1], B.shape[1]
    powers = [np.eye(n)]
    for _ in range(N - 1):
        powers.append(A @ powers[-1])
    Z = np.zeros((N, m, m + n + (N - 1) * nv))
    forced = np.zeros((N, m, N - 1, nu))
    for k in range(N):
        Z[k, :, :m] = -np.eye(m)
        Z[k, :, m : m + n] = -C @ powers[k]
        for i in range(k):
            CA = C @ powers[k - 1 - i]
            Z[k, :, m + n + i * nv : m + n + (i + 1) * nv] = -CA @ E
            forced[k, :, i, :] = CA @ B
    return Z, forced


def model_window(A: np.ndarray, B: np.ndarray, E: np.ndarray, C: np.ndarray, N: int) -> ModelWindow:
    """The window of ``ModelWindow`` for x⁺ = A x + B u + E v, y = Δ(γ) C x + F b.

    Shapes: A (n, n), B (n, n_u), E (n, n_v), C (m, n); N ≥ 2 samples.
    """
    m = C.shape[0]
    Z, forced = stacked_window(A, B, E, C, N)
    weight = 1.0 / np.linalg.norm(C, axis=1)
    Z *= weight[None, :, None]
    forced *= weight[None, :, None, None]
    return ModelWindow(Z.reshape(N * m, -1), forced, weight, complement_projection(Z, forced))


def window_gains(
    window: ModelWindow, y: np.ndarray, u: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """The gains γ ∈ [lower, upper] that best explain a window of readings through the model.

    y (N, m): the readings (NaN where one did not arrive: its equation is dropped); u (N, n_u): the
    known inputs, u(k) acting from sample k to k + 1. Returns γ; the singular values of the
    column-normalized regressor W' Y, whose ratio measures how well the window excites the gains;
    and the relative residual ‖W' (Y β − r)‖ / ‖W' r‖, which is small only if one γ explains the
    whole window through the model (it is not, e.g., when a fault changes inside the window).
    The box 1/upper ≤ β ≤ 1/lower is imposed on β = 1/γ, where the problem is linear.

    Everything after the projection works on the reduced system (``reduced_system``).
    """
    missing = np.isnan(y)
    projection = window.projection
    if missing.any():  # the complement of the nuisance columns within the equations that are left
        kept = ~missing.ravel()
        basis = _complement(window.nuisance[kept])
        complement = np.zeros((len(basis), kept.size))
        complement[:, kept] = basis
        projection = _projection(complement.reshape(len(basis), *y.shape), window.response)
        y = np.where(missing, 0.0, y)
    reduced = reduced_system(projection, y * window.weight, u)
    R, c, rest = reduced[:-1, :-1], reduced[:-1, -1], float(reduced[-1, -1]) ** 2
    scale = np.sqrt(np.einsum("ij,ij->j", R, R))  # a zero column stays zero divided by the smallest float
    sv = singular_values(R / np.maximum(scale, _TINY))
    beta = box_least_squares(R, c, 1.0 / upper, 1.0 / lower)
    misfit = R.dot(beta) - c
    size = float(c.dot(c)) + rest
    residual = float(np.sqrt((misfit.dot(misfit) + rest) / size)) if size > 0 else np.inf
    return 1.0 / beta, sv, residual


def window_gains_runs(
    window: ModelWindow,
    y: np.ndarray,
    u: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    failed: dict[int, str] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``window_gains`` of K windows with every reading (a batch's runs): y (K, N, m), u (K, N, n_u)
    → γ (K, m), the singular values (K, m) and the relative residuals (K,), each run's bit for bit;
    ``failed`` as in ``gains_of_reduced`` (the runs it holds already are not solved)."""
    return gains_of_reduced(reduced_systems(window.projection, y * window.weight, u), lower, upper, failed)


def gains_of_reduced(
    reduced: np.ndarray, lower: np.ndarray, upper: np.ndarray, failed: dict[int, str] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What ``window_gains`` takes from K reduced systems (K, m + 1, m + 1): γ, the singular values
    of the column-normalized regressor and the relative residual of each (the box least squares
    by ``box_least_squares_runs``, the rest on stacks). With ``failed``, a run whose
    least squares raises is recorded there (its γ NaN) and the others go on, and a run it holds
    already is not solved; without, it raises."""
    R, c, rest = reduced[:, :-1, :-1], reduced[:, :-1, -1], np.array([float(v) ** 2 for v in reduced[:, -1, -1]])
    scale = np.sqrt(np.einsum("kij,kij->kj", R, R))  # a zero column stays zero divided by the smallest float
    normalized = R / np.maximum(scale, _TINY)[:, None, :]
    skip = failed or {}  # a run left out (a reading missing: its own projection) is not factorised
    solved = np.array([k not in skip for k in range(len(R))], dtype=bool)
    sv = np.zeros(c.shape)
    sv[solved] = singular_values(normalized[solved])
    beta = np.full(c.shape, np.nan)
    beta[solved], alone = box_least_squares_runs(R[solved], c[solved], 1.0 / upper, 1.0 / lower)
    for k in np.flatnonzero(solved)[alone]:  # rank deficient, not finite or not settled: as alone
        if failed is None:
            beta[k] = box_least_squares(R[k], c[k], 1.0 / upper, 1.0 / lower)
        else:
            try:
                beta[k] = box_least_squares(R[k], c[k], 1.0 / upper, 1.0 / lower)
            except Exception as error:  # noqa: BLE001 (recorded: that run fails, as alone)
                failed[k] = f"{type(error).__name__}: {error}"
    misfit = np.matmul(R, beta[..., None])[..., 0] - c
    size = np.matmul(c[:, None, :], c[:, :, None])[:, 0, 0] + rest
    squares = np.matmul(misfit[:, None, :], misfit[:, :, None])[:, 0, 0] + rest
    with np.errstate(divide="ignore", invalid="ignore"):
        residual = np.where(size > 0, np.sqrt(squares / size), np.inf)
    return 1.0 / beta, sv, residual
