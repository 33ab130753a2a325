"""LMI synthesis of the unknown input observer gains of Behzad, Casavola, Tedesco & Sadrnia,
"Fault-Tolerant Sensor Reconciliation Schemes based on Unknown Input Observers", IJC 2018.

The plant (1)–(2) has sensors with loss of effectiveness Δ(γ) = diag(γ), γ ∈ Γ = [γ̲, γ̄]^m, and a
bias b entering through F. With the bias in the state, x = [x_p; b] (eq. (7)), the augmented model
(8) is

    x⁺ = Ā x + B̄ u + Ē v + F̄ Δb,   y = C̄_γ x,   C̄_γ = [Δ(γ) C_y, F],

and the UIO (10) x̂⁺ = T Ā x̂ + T B̄ u + L (y − C̄_γ̂ x̂) + Q y⁺ decouples the unknown input v when
T = I − Q C̄_γ̂ (11) and T Ē = 0 (12), e.g. with Q = Ē (C̄_γ̂ Ē)⁺ (14). T depends on γ̂ in a
non-convex way; the paper designs L in two ways:

- LPV (Sec. 3.2.1, Theorem 1): vertices (T̃_i, C̃_i) of a polytopic embedding (15) (Remark 2:
  C̃_i = C̄_γi, T̃_i = I − Ē (C̃_i Ē)⁺ C̃_i at the corners γ_i of the box Γ) and parameter-dependent
  matrices P_i, G_i, Y_i from the LMIs (19)–(20), with gains L_i = G_i⁻¹ Y_i (22);
- LFT (Sec. 3.2.2, Theorem 2): T_γ̂ and C̄_γ̂ as linear fractional transformations (34)–(36),
  one gain L = Q⁻¹ S from the single LMI (42).

Both minimise μ, the square of the H∞ bound σ (18), (40) from w = [Δb; L (C_γ − C_γ̂) x] to e.

Transcription errors corrected here (docs/errata.md): the cross-vertex LMI (20) needs −2P_j,
P_i + P_k − 2I and 2μI (the transcription shows +P_j, −I and μI); the parameter-dependent gain
that Theorem 1's proof certifies is L(ρ) = G(ρ)⁻¹ Y(ρ) with G(ρ) = Σ ρ_i G_i, Y(ρ) = Σ ρ_i Y_i
(eq. (16) with (22) agrees with it only when all G_i are equal); in eq. (60)–(61) the left inverse
of G = C_y E is (GᵀG)⁻¹Gᵀ, and Δ⁻¹(γ) = diag(a + b δ), |δ| ≤ 1, has a = (1/γ̲ + 1/γ̄)/2 and
b = (1/γ̲ − 1/γ̄)/2, whose constant part belongs in T11 so that |θ_T| ≤ 1; likewise
θ_C is centred (γ = c + d δ) instead of θ_C = Δ(γ), see ``sensor_fault_lft``.

Theorem 1 is assembled directly into the conic form of the SDP solver Clarabel (or, as a
reference, stated through cvxpy); Theorem 2 goes through cvxpy. Each solution is checked: the
smallest eigenvalue of every LMI at the solution and the spectral radius of the error dynamics
T_γ Ā − L(γ) C̄_γ over the corners and random points of Γ.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse

#: Margin of the strict inequalities (M > 0 is imposed as M ⪰ MARGIN·I).
MARGIN = 1e-6


class DesignError(ValueError):
    """An LMI design is infeasible, or its solution fails the checks."""


# -- the augmented model (7)–(8) and the UIO matrices (11)–(14) ------------------------------


@dataclass(frozen=True)
class SensorFaultModel:
    """The augmented model (8) of a plant (A, B, E, C_y) with sensor gains γ and bias direction F.

    Shapes: A (n, n), B (n, nu), E (n, nv), C (m, n), F (m, q); the augmented state has n + q
    components, x = [x_p; b].
    """

    A: np.ndarray
    B: np.ndarray
    E: np.ndarray
    C: np.ndarray
    F: np.ndarray

    def __post_init__(self) -> None:
        for name in ("A", "B", "E", "C", "F"):
            value = np.atleast_2d(np.asarray(getattr(self, name), dtype=float))
            object.__setattr__(self, name, value)
        n, m = self.A.shape[0], self.C.shape[0]
        if (
            self.A.shape != (n, n)
            or self.B.shape[0] != n
            or self.E.shape[0] != n
            or self.C.shape[1] != n
            or self.F.shape[0] != m
        ):
            raise ValueError(
                f"inconsistent shapes A {self.A.shape}, B {self.B.shape}, E {self.E.shape}, C {self.C.shape}, F "
                f"{self.F.shape}"
            )

    @property
    def n(self) -> int:
        return self.A.shape[0]

    @property
    def m(self) -> int:
        return self.C.shape[0]

    @property
    def q(self) -> int:
        return self.F.shape[1]

    @property
    def Abar(self) -> np.ndarray:
        """Ā = blkdiag(A, I_q), eq. (8)."""
        n, q = self.n, self.q
        return np.block([[self.A, np.zeros((n, q))], [np.zeros((q, n)), np.eye(q)]])

    @property
    def Bbar(self) -> np.ndarray:
        return np.vstack([self.B, np.zeros((self.q, self.B.shape[1]))])

    @property
    def Ebar(self) -> np.ndarray:
        return np.vstack([self.E, np.zeros((self.q, self.E.shape[1]))])

    @property
    def Fbar(self) -> np.ndarray:
        """F̄ = [0; I_q]: how the bias increment Δb enters the augmented state."""
        return np.vstack([np.zeros((self.n, self.q)), np.eye(self.q)])

    def Cbar(self, gamma: np.ndarray) -> np.ndarray:
        """C̄_γ = [Δ(γ) C_y, F], eq. (8), shape (m, n + q)."""
        return np.hstack([np.asarray(gamma, dtype=float)[:, None] * self.C, self.F])

    @property
    def G(self) -> np.ndarray:
        """G = C_y E, so that C̄_γ Ē = Δ(γ) G (Sec. 4)."""
        return self.C @ self.E


def uio_matrices(model: SensorFaultModel, gamma: np.ndarray, *, form: str = "pinv") -> tuple[np.ndarray, np.ndarray]:
    """(Q_γ, T_γ) of the UIO: T = I − Q C̄_γ (11), with T Ē = 0 (12).

    ``form="pinv"``: Q = Ē (C̄_γ Ē)⁺, the Moore–Penrose left inverse of eq. (14) (Algorithm 1);
    ``form="lft"``: Q = Ē G⁺ Δ⁻¹(γ) with G⁺ = (GᵀG)⁻¹Gᵀ, another left inverse of C̄_γ Ē = Δ(γ) G
    (eq. (60)), which makes T affine in Δ⁻¹(γ) (eq. (61)) and is the one Theorem 2's LFT describes.
    """
    gamma = np.asarray(gamma, dtype=float)
    Ebar, Cbar = model.Ebar, model.Cbar(gamma)
    if form == "pinv":
        CE = Cbar @ Ebar
        Q = Ebar @ np.linalg.pinv(CE)
    elif form == "lft":
        Q = Ebar @ np.linalg.pinv(model.G) / gamma[None, :]
    else:
        raise ValueError(f"unknown form {form!r}; use 'pinv' or 'lft'")
    T = np.eye(model.n + model.q) - Q @ Cbar
    return Q, T


def check_assumptions(model: SensorFaultModel, gammas: np.ndarray, tol: float = 1e-9) -> None:
    """Assumption 1 (observability of (C̄_γ, Ā)) and Assumption 2 (rank C̄_γ Ē ≥ rank Ē, eq. (9))
    at the given points of Γ (rows of ``gammas``); a DesignError names the first violation."""
    Abar, Ebar = model.Abar, model.Ebar
    rank_E = np.linalg.matrix_rank(Ebar, tol)
    nx = model.n + model.q
    for gamma in np.atleast_2d(gammas):
        Cbar = model.Cbar(gamma)
        if np.linalg.matrix_rank(Cbar @ Ebar, tol) < rank_E:
            raise DesignError(f"Assumption 2 fails at γ = {gamma.tolist()}: rank(C̄_γ Ē) < rank(Ē) = {rank_E}, eq. (9)")
        for eig in np.linalg.eigvals(Abar):
            if np.linalg.matrix_rank(np.vstack([eig * np.eye(nx) - Abar, Cbar]), 1e-7) < nx:
                raise DesignError(
                    f"Assumption 1 fails at γ = {gamma.tolist()}: the mode λ = {eig:.4g} of Ā is not observable from "
                    "C̄_γ (the bias and the states cannot be told apart); add or change sensors"
                )


# -- the box Γ and its polytopic coordinates ---------------------------------------------------


def box_vertices(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """The 2^m corners of the box [lower, upper], shape (2^m, m); corner v has upper[j] where bit
    j of v is set."""
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    m = lower.size
    bits = np.array(list(itertools.product((0, 1), repeat=m)))[:, ::-1]
    return np.where(bits == 1, upper, lower)


def box_coordinates(gamma: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """ρ(γ) ∈ S_l, l = 2^m: the multilinear (tensor-product) barycentric coordinates of γ in the
    box, ordered as ``box_vertices``. Σ ρ_i = 1, ρ ≥ 0 and Σ ρ_i γ_i = γ; so any map affine in
    each γ_j, like C̄_γ, equals Σ ρ_i C̄_γi exactly (the embedding (15))."""
    lam = np.clip((np.asarray(gamma, dtype=float) - lower) / (np.asarray(upper) - lower), 0.0, 1.0)
    bits = box_vertices(np.zeros(lam.size), np.ones(lam.size))
    return np.prod(np.where(bits == 1, lam, 1.0 - lam), axis=1)


# -- LPV design, Theorem 1 ----------------------------------------------------------------------


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
    solver: str = "CLARABEL",
    margin: float = MARGIN,
    vertices: np.ndarray | None = None,
    backend: str | None = None,
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
    _check(min_eig, margin, "Theorem 1 (LPV-UIO)")
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


def theorem1_min_eigenvalue(TA, C, F, P, G, Y, mu) -> float:
    """The smallest eigenvalue over all LMIs (19)–(20) at the solution (``theorem1_lmis``)."""
    return float(np.linalg.eigvalsh(theorem1_lmis(TA, C, F, P, G, Y, mu)).min())


def theorem1_conic_data(TA: np.ndarray, C: np.ndarray, F: np.ndarray, margin: float = MARGIN):
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
    basis = _svec_basis(nx)
    sizes = [size] * len(pairs)
    blocks = []  # (row offset, column offset, coefficients of the cone rows in those columns)
    b = []
    row = 0
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
    # S_r − P_j ⪰ 0 for every pair r and vertex j: svec(S_r) − svec(P_j), identity blocks.
    pair, vertex, entry = (
        g.ravel() for g in np.meshgrid(np.arange(len(pairs)), np.arange(l), np.arange(nt), indexing="ij")
    )
    small_rows = row + np.arange(pair.size)
    sizes += [nx] * (len(pairs) * l)
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


def _theorem1_direct(TA, C, F, margin, solver):
    """Theorem 1 through ``theorem1_conic_data``, solved by Clarabel; returns μ, P, G, Y."""
    import clarabel

    l, nx, _ = F.shape
    m = C.shape[1]
    c, A, b, sizes, layout = theorem1_conic_data(TA, C, F, margin)
    settings = clarabel.DefaultSettings()
    # One thread: the factorization is then reproducible to the bit, and no slower here.
    options = {**_CLARABEL_OPTIONS, "verbose": False, "max_threads": 1, "input_sparse_dropzeros": False}
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
        raise DesignError(f"Theorem 1 (LPV-UIO): {_INFEASIBLE.format(status='infeasible')}")
    if status not in ("Solved", "AlmostSolved"):
        raise DesignError(f'Theorem 1 (LPV-UIO): Clarabel stopped with status {status}; try backend="cvxpy"')
    x = np.asarray(solution.x)
    P = _smat(x[layout["P"]].reshape(l, -1), nx)
    G = x[layout["G"]].reshape(l, nx, nx).transpose(0, 2, 1)
    Y = x[layout["Y"]].reshape(l, m, nx).transpose(0, 2, 1)
    return float(x[layout["mu"]]), P, G, Y


def _theorem1_cvxpy(TA, C, F, margin, solver):
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
    _solve(problem, solver, "Theorem 1 (LPV-UIO)")
    return float(_solved(mu.value, "Theorem 1 (LPV-UIO)")), *(np.array([v.value for v in group]) for group in (P, G, Y))


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


# -- LFT design, Theorem 2 ----------------------------------------------------------------------


@dataclass(frozen=True)
class SensorFaultLft:
    """The LFT form (34)–(35) of T_γ̂ and C̄_γ̂ for sensor gain faults (eq. (60)–(61)):

    T_γ̂ = T11 + T12 θ_T T21 and C̄_γ̂ = C11 + C12 θ_C C21 with θ_T = diag(δ_T), θ_C = diag(δ_C),
    |δ| ≤ 1, where 1/γ̂_j = a_j + b_j δ_T,j and γ̂_j = c_j + d_j δ_C,j (T22 = C22 = 0, so D_qp = 0).
    """

    T11: np.ndarray
    T12: np.ndarray
    T21: np.ndarray
    C11: np.ndarray
    C12: np.ndarray
    C21: np.ndarray


def sensor_fault_lft(model: SensorFaultModel, lower: np.ndarray, upper: np.ndarray) -> SensorFaultLft:
    """The LFT of eq. (60)–(61), normalized so that |θ| ≤ 1 holds on Γ = [lower, upper]:

    - T: 1/γ_j = a_j + b_j δ_j with a = (1/γ̲ + 1/γ̄)/2, b = (1/γ̲ − 1/γ̄)/2 (the paper's "standard
      normalization"; its constant part a goes into T11);
    - C̄: γ_j = c_j + d_j δ_j with c = (γ̲ + γ̄)/2, d = (γ̄ − γ̲)/2. The paper takes θ_C = Δ(γ)
      itself, which is valid (0 ≤ γ ≤ 1) but leaves C11 = [0 F], a nominal output that sees no
      plant state; with it the LMI (42) is infeasible on every box we tried, the centred form is
      what makes the S-procedure bite (docs/three-tank.md).
    """
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    if np.any(lower <= 0) or np.any(upper > 1) or np.any(lower >= upper):
        raise DesignError(f"Γ must satisfy 0 < γ̲ < γ̄ ≤ 1 (got γ̲ = {lower.tolist()}, γ̄ = {upper.tolist()})")
    n, q, m = model.n, model.q, model.m
    nx = n + q
    a, b = (1.0 / lower + 1.0 / upper) / 2.0, (1.0 / lower - 1.0 / upper) / 2.0
    c, d = (lower + upper) / 2.0, (upper - lower) / 2.0
    EG = model.Ebar @ np.linalg.pinv(model.G)  # Ē G⁺, shape (nx, m)
    Cy0 = np.hstack([model.C, np.zeros((m, q))])  # [C_y 0]
    ZF = np.hstack([np.zeros((m, n)), model.F])  # [0 F]
    return SensorFaultLft(
        T11=np.eye(nx) - EG @ Cy0 - EG @ (a[:, None] * ZF),
        T12=-EG * b[None, :],
        T21=ZF,
        C11=ZF + c[:, None] * Cy0,
        C12=np.diag(d),
        C21=Cy0,
    )


@dataclass(frozen=True)
class LftDesign:
    """Solution of Theorem 2: the constant gain L = Q⁻¹ S, the Lyapunov matrix Q and the S-procedure
    multipliers λ (one, or one per uncertainty channel)."""

    L: np.ndarray
    Q: np.ndarray
    lam: np.ndarray
    mu: float
    min_eigenvalue: float
    seconds: float

    @property
    def sigma(self) -> float:
        """σ = √μ*, eq. (43)."""
        return float(np.sqrt(self.mu))


def lft_uio_design(
    model: SensorFaultModel,
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    solver: str = "CLARABEL",
    margin: float = MARGIN,
    multiplier: str = "scalar",
) -> LftDesign:
    """Theorem 2: minimise μ subject to the LMI (42) in Q = Qᵀ ≻ 0, S, λ > 0:

        [[Q, Q T11 Ā − S C11, [Q T12, −S C12], Q F_e],
         [⋆, Q − I − λ C_qxᵀ C_qx, −λ C_qxᵀ D_qp, −λ C_qxᵀ F_w],
         [⋆, ⋆, λ (I − D_qpᵀ D_qp), −λ D_qpᵀ F_w],
         [⋆, ⋆, ⋆, μ I − λ F_wᵀ F_w]] ≻ 0,

    with C_qx = [T21 Ā; C21], D_qp = 0, F_e = [T11 F̄, I], F_w = [[T21 F̄, 0]; [0, 0]] (eq. (34),
    (37)–(38)); L = Q⁻¹ S. ``multiplier="scalar"`` is the theorem's S-procedure, which treats the
    uncertainty as one full block with ‖p̃‖ ≤ ‖q̃‖ (48); ``"diagonal"`` uses one λ_i per channel
    (λ I → Λ = diag(λ_i)), the S-procedure for the diagonal Θ (35) that the plant actually has:
    it contains the scalar case, so its μ* is never larger.
    """
    import cvxpy as cp

    if multiplier not in ("scalar", "diagonal"):
        raise ValueError(f"unknown multiplier {multiplier!r}; use 'scalar' or 'diagonal'")
    lft = sensor_fault_lft(model, lower, upper)
    check_assumptions(model, box_vertices(lower, upper))
    Abar, Fbar = model.Abar, model.Fbar
    nx, m, q = model.n + model.q, model.m, model.q
    Cqx = np.vstack([lft.T21 @ Abar, lft.C21])  # (2m, nx)
    Fe = np.hstack([lft.T11 @ Fbar, np.eye(nx)])  # (nx, q + nx)
    nw, npq = Fe.shape[1], 2 * m
    Fw = np.zeros((npq, nw))
    Fw[:m, :q] = lft.T21 @ Fbar
    start = time.perf_counter()
    Qv = cp.Variable((nx, nx), symmetric=True)
    S = cp.Variable((nx, m))
    mu = cp.Variable()
    lam = cp.Variable(1 if multiplier == "scalar" else npq)
    Lam = lam * np.eye(npq) if multiplier == "scalar" else cp.diag(lam)
    row1 = [Qv, Qv @ lft.T11 @ Abar - S @ lft.C11, cp.hstack([Qv @ lft.T12, -S @ lft.C12]), Qv @ Fe]
    M = cp.bmat(
        [
            row1,
            [row1[1].T, Qv - np.eye(nx) - Cqx.T @ Lam @ Cqx, np.zeros((nx, npq)), -Cqx.T @ Lam @ Fw],
            [row1[2].T, np.zeros((npq, nx)), Lam, np.zeros((npq, nw))],
            [row1[3].T, (-Cqx.T @ Lam @ Fw).T, np.zeros((nw, npq)), mu * np.eye(nw) - Fw.T @ Lam @ Fw],
        ]
    )
    size = 2 * nx + npq + nw
    problem = cp.Problem(cp.Minimize(mu), [M >> margin * np.eye(size), Qv >> margin * np.eye(nx), lam >= margin])
    _solve(problem, solver, "Theorem 2 (LFT-UIO)")
    seconds = time.perf_counter() - start
    min_eig = float(np.linalg.eigvalsh((M.value + M.value.T) / 2).min())
    _check(min_eig, margin, "Theorem 2 (LFT-UIO)")
    Q_value, S_value, lam_value, mu_value = (_solved(v.value, "Theorem 2 (LFT-UIO)") for v in (Qv, S, lam, mu))
    return LftDesign(
        np.linalg.solve(Q_value, S_value), Q_value, np.atleast_1d(lam_value), float(mu_value), min_eig, seconds
    )


# -- checks ------------------------------------------------------------------------------------


def max_spectral_radius(
    model: SensorFaultModel, gain, lower, upper, *, form: str = "pinv", samples: int = 200, seed: int = 0
) -> float:
    """max over γ of ρ(T_γ Ā − L(γ) C̄_γ), the error dynamics (17)/(37) with γ̂ = γ, at the corners
    of Γ and ``samples`` random points; ``gain`` maps γ to L (shape (nx, m))."""
    rng = np.random.default_rng(seed)
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    points = np.vstack([box_vertices(lower, upper), lower + (upper - lower) * rng.random((samples, lower.size))])
    Abar = model.Abar
    worst = 0.0
    for gamma in points:
        T = uio_matrices(model, gamma, form=form)[1]
        N = T @ Abar - gain(gamma) @ model.Cbar(gamma)
        worst = max(worst, float(np.max(np.abs(np.linalg.eigvals(N)))))
    return worst


# Clarabel's chordal decomposition splits these dense LMIs into many more, smaller cones and
# solves slower here; 1e-7 is ample for a certificate that is re-checked afterwards.
_CLARABEL_OPTIONS = {"chordal_decomposition_enable": False, "tol_gap_abs": 1e-7, "tol_gap_rel": 1e-7, "tol_feas": 1e-7}
_INFEASIBLE = "the LMIs are {status}; the design has no solution on this Γ (narrow Γ or check the model)"


def _solve(problem, solver: str, what: str) -> None:
    import cvxpy as cp

    options = _CLARABEL_OPTIONS if solver == "CLARABEL" else {}
    try:
        problem.solve(solver=solver, **options)
    except cp.error.SolverError as error:
        raise DesignError(f'{what}: the SDP solver {solver} failed ({error}); try solver = "SCS"') from None
    if problem.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
        raise DesignError(f"{what}: {_INFEASIBLE.format(status=problem.status)}")


def _solved(value: np.ndarray | None, what: str) -> np.ndarray:
    """A variable's value after ``_solve`` returned (an optimal status sets every variable; cvxpy
    types ``value`` optional, None before a solve)."""
    if value is None:
        raise DesignError(f"{what}: the SDP solver reported a solution but left a variable without a value")
    return value


def _check(min_eig: float, margin: float, what: str) -> None:
    # The solver's tolerance may leave the constraint margin slightly violated; a negative
    # eigenvalue beyond it means the certificate is invalid.
    if min_eig < -1e-7:
        raise DesignError(f"{what}: the solution violates the LMI (smallest eigenvalue {min_eig:.3g} < 0)")
