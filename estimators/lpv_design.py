"""Theorem 1 of IJC 2018 (Behzad et al.): the LPV design of the UIO gain, L(ρ) = G(ρ)⁻¹ Y(ρ)
(Sec. 3.2.1, eq. (19)–(22)), over the vertices of the box Γ (Remark 2).

It is assembled directly into the conic form of the SDP solver Clarabel (``theorem1_conic_data``)
or, as a reference, stated through cvxpy with every LMI (19)–(20) as printed (corrected:
docs/errata.md).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse

from estimators.lmi import (
    CLARABEL_OPTIONS,
    INFEASIBLE,
    MARGIN,
    DesignError,
    SensorFaultModel,
    box_coordinates,
    box_vertices,
    check_assumptions,
    check_certificate,
    solve_problem,
    solved_value,
    uio_matrices,
)


@dataclass(frozen=True)
class LpvDesign:
    """Solution of Theorem 1: per vertex γ_i of Γ, the matrices T̃_i, C̃_i of the embedding and
    P_i, G_i, Y_i; the gain at ρ is L(ρ) = G(ρ)⁻¹ Y(ρ)."""

    vertices: np.ndarray  # (l, m)
    T: np.ndarray  # (l, nx, nx)
    C: np.ndarray  # (l, m, nx)
    P: np.ndarray  # (l, nx, nx)
    G: np.ndarray  # (l, nx, nx)
    Y: np.ndarray  # (l, nx, m)
    mu: float
    min_eigenvalue: float
    seconds: float
    lower: np.ndarray
    upper: np.ndarray

    @property
    def sigma(self) -> float:
        """The guaranteed H∞ gain σ = √μ*, eq. (21)."""
        return float(np.sqrt(self.mu))

    def gain(self, gamma: np.ndarray) -> np.ndarray:
        """L(ρ̂(γ̂)) = G(ρ̂)⁻¹ Y(ρ̂), shape (nx, m)."""
        rho = box_coordinates(gamma, self.lower, self.upper)
        return np.linalg.solve(np.tensordot(rho, self.G, axes=1), np.tensordot(rho, self.Y, axes=1))

    @property
    def vertex_gains(self) -> np.ndarray:
        """L_i = G_i⁻¹ Y_i, eq. (22)."""
        return np.linalg.solve(self.G, self.Y)


def lpv_uio_design(
    model: SensorFaultModel,
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    vertices: np.ndarray | None = None,
    backend: str | None = None,
    solver: str = "CLARABEL",
    margin: float = MARGIN,
) -> LpvDesign:
    """Theorem 1 on the box Γ = [lower, upper] with the vertices of Remark 2.

    For every vertex pair (i, j), Ξ_ij ≻ 0 (19):
        [[G_i + G_iᵀ − P_j, G_i T̃_i Ā − Y_i C̃_i, G_i F_i], [⋆, P_i − I, 0], [⋆, ⋆, μ I]],
    and for i < k and every j, Ξ_ijk ≻ 0 (20, corrected):
        [[G_i + G_iᵀ + G_k + G_kᵀ − 2P_j, G_i T̃_k Ā + G_k T̃_i Ā − Y_i C̃_k − Y_k C̃_i, G_i F_k + G_k F_i],
         [⋆, P_i + P_k − 2I, 0], [⋆, ⋆, 2μ I]],
    with F_i = [T̃_i F̄, I]; minimise μ. (Then (33) holds for all ρ̂, ϱ in the simplex.)
    ``vertices`` replaces the corners of the box (one vertex gives the LTI H∞ UIO design).

    ``backend="direct"`` (the default with Clarabel) solves the equivalent problem of
    ``theorem1_conic_data``, which has the same μ* with l(l+1)/2 LMIs of the size of Ξ (and
    l²(l+1)/2 of size n + q) instead of l²(l+1)/2, assembled straight into Clarabel's conic form.
    ``backend="cvxpy"`` (the default with any other ``solver``) states (19)–(20) as printed, every
    (i, j) and (i, k, j), through cvxpy: the reference, about ten times slower. Either way the
    solution is checked on every LMI (19)–(20) (``theorem1_min_eigenvalue``).
    """
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    vertices = box_vertices(lower, upper) if vertices is None else np.atleast_2d(vertices)
    backend = ("direct" if solver.upper() == "CLARABEL" else "cvxpy") if backend is None else backend
    if backend not in ("direct", "cvxpy"):
        raise ValueError(f"unknown backend {backend!r}; use 'direct' (Clarabel) or 'cvxpy'")
    if backend == "direct" and solver.upper() != "CLARABEL":
        raise ValueError(f"backend 'direct' solves with Clarabel only; use backend='cvxpy' for solver {solver!r}")
    check_assumptions(model, vertices)
    Abar, Fbar = model.Abar, model.Fbar
    Ts = np.array([uio_matrices(model, g)[1] for g in vertices])
    Cs = np.array([model.Cbar(g) for g in vertices])
    TA = Ts @ Abar
    Fs = np.concatenate([Ts @ Fbar, np.broadcast_to(np.eye(Abar.shape[0]), Ts.shape)], axis=2)
    start = time.perf_counter()
    solve = _theorem1_direct if backend == "direct" else _theorem1_cvxpy
    mu, P, G, Y = solve(TA, Cs, Fs, margin, solver)
    seconds = time.perf_counter() - start
    min_eig = theorem1_min_eigenvalue(TA, Cs, Fs, P, G, Y, mu)
    check_certificate(min_eig, margin, "Theorem 1 (LPV-UIO)")
    return LpvDesign(vertices, Ts, Cs, P, G, Y, mu, min_eig, seconds, lower, upper)


def theorem1_lmis(
    TA: np.ndarray, C: np.ndarray, F: np.ndarray, P: np.ndarray, G: np.ndarray, Y: np.ndarray, mu: float
) -> np.ndarray:
    """Every LMI of Theorem 1 at a given point: Ξ_ij (19) for all (i, j), then Ξ_ijk (20,
    corrected) for i < k and all j, as printed in ``lpv_uio_design``.

    Shapes: TA = T̃_i Ā (l, nx, nx), C = C̃_i (l, m, nx), F = F_i (l, nx, nw), P, G (l, nx, nx),
    Y (l, nx, m); returns (l² + l²(l−1)/2, 2nx + nw, 2nx + nw).
    """
    l, nx, nw = F.shape
    eye = np.eye(nx)
    top = G[:, None] @ TA[None, :] - Y[:, None] @ C[None, :]  # top[i, k] = G_i T̃_k Ā − Y_i C̃_k
    right = G[:, None] @ F[None, :]  # right[i, k] = G_i F_k
    sym_G = G + G.transpose(0, 2, 1)
    i, k = np.triu_indices(l, 1)
    # One row per (i, k) pair: i = k gives (19), i < k the cross terms of (20).
    rows = [
        (sym_G, top[np.arange(l), np.arange(l)], right[np.arange(l), np.arange(l)], P - eye, 1.0),
        (sym_G[i] + sym_G[k], top[i, k] + top[k, i], right[i, k] + right[k, i], P[i] + P[k] - 2 * eye, 2.0),
    ]
    lmis = []
    for diag, off, gf, lyap, scale in rows:
        n = len(diag)
        M = np.zeros((n, l, 2 * nx + nw, 2 * nx + nw))
        M[..., :nx, :nx] = diag[:, None] - scale * P[None, :]
        M[..., :nx, nx : 2 * nx] = off[:, None]
        M[..., :nx, 2 * nx :] = gf[:, None]
        M[..., nx : 2 * nx, nx : 2 * nx] = lyap[:, None]
        M[..., 2 * nx :, 2 * nx :] = scale * mu * np.eye(nw)
        M[..., nx:, :nx] = M[..., :nx, nx:].swapaxes(-1, -2)
        lmis.append(M.reshape(n * l, *M.shape[2:]))
    return np.concatenate(lmis)


def theorem1_min_eigenvalue(
    TA: np.ndarray, C: np.ndarray, F: np.ndarray, P: np.ndarray, G: np.ndarray, Y: np.ndarray, mu: float
) -> float:
    """The smallest eigenvalue over all LMIs (19)–(20) at the solution (``theorem1_lmis``)."""
    return float(np.linalg.eigvalsh(theorem1_lmis(TA, C, F, P, G, Y, mu)).min())


#: Clarabel's problem data: cost c, constraint matrix A, b, the PSD cones' sizes, where μ, P, G, Y lie in x.
ConicData = tuple[np.ndarray, scipy.sparse.csc_matrix, np.ndarray, list[int], dict[str, Any]]


def theorem1_conic_data(TA: np.ndarray, C: np.ndarray, F: np.ndarray, margin: float = MARGIN) -> ConicData:
    """Theorem 1 in Clarabel's conic form: minimise cᵀx subject to b − A x ∈ K, K a product of
    PSD cones in Clarabel's triangle form (upper triangle by columns, off-diagonal entries × √2).

    The LMIs (19)–(20) come in families that differ only in the −P_j (or −2P_j) of the first
    diagonal block. For each pair (i, k), i ≤ k, with Ξ̂_ik(S) the LMI of the family with P_j
    replaced by a new symmetric variable S_ik, the family is equivalent to

        Ξ̂_ik(S_ik) ⪰ margin·I  and  S_ik ⪰ P_j for every j:

    given these, Ξ_ij(k) = Ξ̂_ik + blkdiag(c(S_ik − P_j), 0, 0) ⪰ margin·I (c = 1, or 2 if i < k);
    conversely, by the Schur complement on the lower-right block (which does not depend on j),
    every Ξ_ij(k) ≻ 0 says P_j ≺ R_ik(G, Y, P_i, P_k, μ), a matrix that does not depend on j, and
    S_ik = R_ik − εI passes for a small ε. So the optimum μ* is that of (19)–(20), with
    l(l+1)/2 LMIs of size 2nx + nw and l²(l+1)/2 of size nx in place of l²(l+1)/2 of size
    2nx + nw (three-tank, l = 16: 136 + 2176 × 4×4 instead of 2176 × 13×13), and the lower-right
    blocks P_i − I ≻ 0 imply P_i ≻ 0.

    Each Ξ̂ is linear in the variables through He(E₁ᵀ (G_i K_k − Y_i J_k)) with K_k = [I, T̃_kĀ, F_k],
    J_k = [0, C̃_k, 0] and E₁ = [I, 0, 0]: Ξ̂_ii = He(E₁ᵀ(G_i K_i − Y_i J_i)) + blkdiag(−S_ii, P_i − I, μI)
    and Ξ̂_ik = that of (i, k) plus that of (k, i) for i < k.

    Variables x = [μ, svec P_1…P_l, vec G_1…G_l, vec Y_1…Y_l, svec S_11, S_22, …, S_12, …]
    (vec by columns). Returns (c, A, b, cone sizes, layout) with layout the slices of μ, P, G, Y.
    """
    l, nx, nw = F.shape
    m = C.shape[1]
    size = 2 * nx + nw
    nt = nx * (nx + 1) // 2
    pairs = [(i, i) for i in range(l)] + [(i, k) for i in range(l) for k in range(i + 1, l)]
    off_P, off_G = 1, 1 + l * nt
    off_Y = off_G + l * nx * nx
    off_S = off_Y + l * nx * m
    n_var = off_S + len(pairs) * nt
    K = np.concatenate([np.broadcast_to(np.eye(nx), TA.shape), TA, F], axis=2)  # (l, nx, size)
    J = np.concatenate([np.zeros((l, m, nx)), C, np.zeros((l, m, nw))], axis=2)  # (l, m, size)
    blocks, b, row = _xi_cones(K, J, pairs, (off_P, off_G, off_Y, off_S), margin)
    # S_r − P_j ⪰ 0 for every pair r and vertex j: svec(S_r) − svec(P_j), identity blocks.
    pair, vertex, entry = (
        g.ravel() for g in np.meshgrid(np.arange(len(pairs)), np.arange(l), np.arange(nt), indexing="ij")
    )
    small_rows = row + np.arange(pair.size)
    sizes = [size] * len(pairs) + [nx] * (len(pairs) * l)
    b.append(np.zeros(pair.size))
    rows = [small_rows, small_rows]
    cols = [off_S + pair * nt + entry, off_P + vertex * nt + entry]
    vals = [-np.ones(pair.size), np.ones(pair.size)]
    for row0, col0, coef in blocks:
        nz_r, nz_c = np.nonzero(coef)
        rows.append(row0 + nz_r)
        cols.append(col0 + nz_c)
        vals.append(-coef[nz_r, nz_c])
    A = scipy.sparse.csc_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(row + pair.size, n_var)
    )
    cost = np.zeros(n_var)
    cost[0] = 1.0
    layout = {"mu": 0, "P": slice(off_P, off_G), "G": slice(off_G, off_Y), "Y": slice(off_Y, off_S)}
    return cost, A, np.concatenate(b), sizes, layout


def _xi_cones(
    K: np.ndarray, J: np.ndarray, pairs: list[tuple[int, int]], offsets: tuple[int, int, int, int], margin: float
) -> tuple[list[tuple[int, int, np.ndarray]], list[np.ndarray], int]:
    """The cones Ξ̂_ik(S_ik) ⪰ margin·I of ``theorem1_conic_data``, one per pair (i, k): the blocks
    (row offset, column offset, coefficients of the cone's rows in those columns) of A, the cones'
    constant parts b, and the rows they take. ``offsets``: the columns of P_1, G_1, Y_1 and S_11."""
    (_, nx, size), m = K.shape, J.shape[1]
    nw, nt = size - 2 * nx, nx * (nx + 1) // 2
    off_P, off_G, off_Y, off_S = offsets
    basis = _svec_basis(nx)
    blocks, b, row = [], [], 0
    for r, (i, k) in enumerate(pairs):
        const = -margin * np.eye(size)
        for first, second in ((i, k), (k, i)) if i != k else ((i, i),):
            terms = [
                (off_G + first * nx * nx, _first_row_coefficients(K[second], nx)),
                (off_Y + first * nx * m, -_first_row_coefficients(J[second], nx)),
                (off_P + first * nt, _placed(basis, size, nx)),
                (off_S + r * nt, -_placed(basis, size, 0)),
                (0, _placed(np.eye(nw)[None], size, 2 * nx)),
            ]
            blocks += [(row, column, _svec(coef).T) for column, coef in terms]
            const[nx : 2 * nx, nx : 2 * nx] -= np.eye(nx)
        b.append(_svec(const))
        row += size * (size + 1) // 2
    return blocks, b, row


def _theorem1_direct(
    TA: np.ndarray, C: np.ndarray, F: np.ndarray, margin: float, solver: str
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Theorem 1 through ``theorem1_conic_data``, solved by Clarabel; returns μ, P, G, Y."""
    import clarabel

    l, nx, _ = F.shape
    m = C.shape[1]
    c, A, b, sizes, layout = theorem1_conic_data(TA, C, F, margin)
    settings = clarabel.DefaultSettings()
    # One thread: the factorization is then reproducible to the bit, and no slower here.
    options = {**CLARABEL_OPTIONS, "verbose": False, "max_threads": 1, "input_sparse_dropzeros": False}
    for name, value in options.items():
        setattr(settings, name, value)
    # Clarabel orders its KKT system by approximate minimum degree, which would eliminate the
    # shared variables μ, P_i, G_i, Y_i (each in a few rows of many cones) before the cones' dense
    # blocks and so fuse the cones together (three-tank: 0.9 s per iteration instead of 0.24 s).
    # A quadratic term that is zero but structurally dense on them makes them look dense to the
    # ordering, which then keeps them for last, as a Schur-complement method would.
    shared = layout["Y"].stop  # μ, P, G, Y come first in x
    column, row = np.tril_indices(shared)  # upper triangle by columns, the CSC order
    indptr = np.concatenate([[0], np.cumsum(np.arange(1, shared + 1)), np.full(len(c) - shared, row.size)])
    zero_pattern = scipy.sparse.csc_matrix((np.zeros(row.size), row, indptr), shape=(len(c), len(c)))
    cones = [clarabel.PSDTriangleConeT(n) for n in sizes]
    solution = clarabel.DefaultSolver(zero_pattern, c, A, b, cones, settings).solve()
    status = str(solution.status)
    if status in ("PrimalInfeasible", "AlmostPrimalInfeasible"):
        raise DesignError(f"Theorem 1 (LPV-UIO): {INFEASIBLE.format(status='infeasible')}")
    if status not in ("Solved", "AlmostSolved"):
        raise DesignError(f'Theorem 1 (LPV-UIO): Clarabel stopped with status {status}; try backend="cvxpy"')
    x = np.asarray(solution.x)
    P = _smat(x[layout["P"]].reshape(l, -1), nx)
    G = x[layout["G"]].reshape(l, nx, nx).transpose(0, 2, 1)
    Y = x[layout["Y"]].reshape(l, m, nx).transpose(0, 2, 1)
    return float(x[layout["mu"]]), P, G, Y


def _theorem1_cvxpy(
    TA: np.ndarray, C: np.ndarray, F: np.ndarray, margin: float, solver: str
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Theorem 1 with (19)–(20) as printed, every (i, j) and (i, k, j), through cvxpy; returns μ, P, G, Y."""
    import cvxpy as cp

    l, nx, nw = F.shape
    m = C.shape[1]
    P = [cp.Variable((nx, nx), symmetric=True) for _ in range(l)]
    G = [cp.Variable((nx, nx)) for _ in range(l)]
    Y = [cp.Variable((nx, m)) for _ in range(l)]
    mu = cp.Variable()
    I, Z = np.eye(nx), np.zeros((nx, nw))
    blocks = []
    for i in range(l):
        top = G[i] @ TA[i] - Y[i] @ C[i]
        for j in range(l):
            blocks.append(
                cp.bmat(
                    [
                        [G[i] + G[i].T - P[j], top, G[i] @ F[i]],
                        [top.T, P[i] - I, Z],
                        [(G[i] @ F[i]).T, Z.T, mu * np.eye(nw)],
                    ]
                )
            )
    for i in range(l - 1):
        for k in range(i + 1, l):
            top = G[i] @ TA[k] + G[k] @ TA[i] - Y[i] @ C[k] - Y[k] @ C[i]
            right = G[i] @ F[k] + G[k] @ F[i]
            for j in range(l):
                blocks.append(
                    cp.bmat(
                        [
                            [G[i] + G[i].T + G[k] + G[k].T - 2 * P[j], top, right],
                            [top.T, P[i] + P[k] - 2 * I, Z],
                            [right.T, Z.T, 2 * mu * np.eye(nw)],
                        ]
                    )
                )
    size = 2 * nx + nw
    # Each block is symmetric by construction (lower blocks are transposes of upper ones).
    constraints = [B >> margin * np.eye(size) for B in blocks]
    constraints += [p >> margin * I for p in P]
    problem = cp.Problem(cp.Minimize(mu), constraints)
    solve_problem(problem, solver, "Theorem 1 (LPV-UIO)")
    mu_value = float(solved_value(mu.value, "Theorem 1 (LPV-UIO)"))
    P_value, G_value, Y_value = (np.array([v.value for v in group]) for group in (P, G, Y))
    return mu_value, P_value, G_value, Y_value


def _svec_indices(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(row, column) of the upper triangle of an n×n matrix, by columns (Clarabel's order)."""
    column, row = np.tril_indices(n)
    return row, column


def _svec(M: np.ndarray) -> np.ndarray:
    """svec of the symmetric matrices M (..., n, n): upper triangle by columns, off-diagonal × √2."""
    row, column = _svec_indices(M.shape[-1])
    return M[..., row, column] * np.where(row == column, 1.0, np.sqrt(2.0))


def _svec_basis(n: int) -> np.ndarray:
    """The symmetric matrices E_t with svec(E_t) = e_t, shape (n(n+1)/2, n, n)."""
    row, column = _svec_indices(n)
    t = np.arange(row.size)
    E = np.zeros((row.size, n, n))
    scale = np.where(row == column, 1.0, 1.0 / np.sqrt(2.0))
    E[t, row, column] = scale
    E[t, column, row] = scale
    return E


def _smat(v: np.ndarray, n: int) -> np.ndarray:
    """Inverse of ``_svec``: v (..., n(n+1)/2) to symmetric matrices (..., n, n)."""
    return np.tensordot(v, _svec_basis(n), axes=1)


def _placed(coef: np.ndarray, size: int, at: int) -> np.ndarray:
    """Coefficient matrices (t, n, n) placed as the diagonal block starting at row and column ``at``
    of size×size matrices."""
    n = coef.shape[-1]
    out = np.zeros((len(coef), size, size))
    out[:, at : at + n, at : at + n] = coef
    return out


def _first_row_coefficients(K: np.ndarray, rows: int) -> np.ndarray:
    """Coefficients of X ↦ He(E₁ᵀ X K) in the entries of X (rows × c, by columns), E₁ = [I_rows, 0]:
    shape (rows·c, s, s) for K of shape (c, s). The entry (a, b) of X puts K[b] in row a."""
    c, size = K.shape
    U = np.zeros((c, rows, size, size))
    a = np.arange(rows)
    U[:, a, a, :] = K[:, None, :]
    stacked = U.reshape(c * rows, size, size)
    return stacked + stacked.transpose(0, 2, 1)
