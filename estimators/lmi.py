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

This module holds what both designs share: the augmented model, the UIO matrices, the box Γ, the
solver's settings and the checks. Theorem 1 is in ``estimators.lpv_design``, Theorem 2 in
``estimators.lft_design``. Each solution is checked: the smallest eigenvalue of every LMI at the
solution and the spectral radius of the error dynamics T_γ Ā − L(γ) C̄_γ over the corners and
random points of Γ.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import lapack

if TYPE_CHECKING:
    import cvxpy as cp

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

    @functools.cached_property
    def Abar(self) -> np.ndarray:
        """Ā = blkdiag(A, I_q), eq. (8)."""
        n, q = self.n, self.q
        return np.block([[self.A, np.zeros((n, q))], [np.zeros((q, n)), np.eye(q)]])

    @functools.cached_property
    def Bbar(self) -> np.ndarray:
        return np.vstack([self.B, np.zeros((self.q, self.B.shape[1]))])

    @functools.cached_property
    def Ebar(self) -> np.ndarray:
        return np.vstack([self.E, np.zeros((self.q, self.E.shape[1]))])

    @functools.cached_property
    def Fbar(self) -> np.ndarray:
        """F̄ = [0; I_q]: how the bias increment Δb enters the augmented state."""
        return np.vstack([np.zeros((self.n, self.q)), np.eye(self.q)])

    def Cbar(self, gamma: np.ndarray) -> np.ndarray:
        """C̄_γ = [Δ(γ) C_y, F], eq. (8), shape (m, n + q)."""
        Cbar = self._Cbar_template.copy()  # the reconciliators build one every tick: no np.hstack
        np.multiply(np.asarray(gamma, dtype=float)[:, None], self.C, out=Cbar[:, : self.n])
        return Cbar

    def Cbars(self, gammas: np.ndarray) -> np.ndarray:
        """C̄_γ of each row of ``gammas`` (K, m), shape (K, m, n + q): ``Cbar``'s of each, bit for bit."""
        Cbars = np.repeat(self._Cbar_template[None], len(gammas), axis=0)
        np.multiply(np.asarray(gammas, dtype=float)[:, :, None], self.C, out=Cbars[:, :, : self.n])
        return Cbars

    @functools.cached_property
    def _Cbar_template(self) -> np.ndarray:
        return np.hstack([np.zeros_like(self.C), self.F])

    @functools.cached_property
    def Ebar_G_pinv(self) -> np.ndarray:
        """Ē G⁺ (G⁺ = (GᵀG)⁻¹Gᵀ), the constant factor of Q in eq. (60)."""
        return self.Ebar @ np.linalg.pinv(self.G)

    @functools.cached_property
    def G(self) -> np.ndarray:
        """G = C_y E, so that C̄_γ Ē = Δ(γ) G (Sec. 4)."""
        return self.C @ self.E


def uio_matrices(
    model: SensorFaultModel, gamma: np.ndarray, *, form: str = "pinv", Cbar: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(Q_γ, T_γ) of the UIO: T = I − Q C̄_γ (11), with T Ē = 0 (12).

    ``form="pinv"``: Q = Ē (C̄_γ Ē)⁺, the Moore–Penrose left inverse of eq. (14) (Algorithm 1);
    ``form="lft"``: Q = Ē G⁺ Δ⁻¹(γ) with G⁺ = (GᵀG)⁻¹Gᵀ, another left inverse of C̄_γ Ē = Δ(γ) G
    (eq. (60)), which makes T affine in Δ⁻¹(γ) (eq. (61)) and is the one Theorem 2's LFT describes.
    ``Cbar``: C̄_γ, where the caller has it already.
    """
    gamma = np.asarray(gamma, dtype=float)
    Ebar = model.Ebar
    Cbar = model.Cbar(gamma) if Cbar is None else Cbar
    if form == "pinv":
        Q = Ebar.dot(pseudo_inverse(Cbar.dot(Ebar)))
    elif form == "lft":
        Q = model.Ebar_G_pinv / gamma[None, :]
    else:
        raise ValueError(f"unknown form {form!r}; use 'pinv' or 'lft'")
    T = -Q.dot(Cbar)
    T.flat[:: T.shape[0] + 1] += 1.0  # I − Q C̄, without building I
    return Q, T


def uio_matrices_runs(
    model: SensorFaultModel, gammas: np.ndarray, Cbars: np.ndarray, *, form: str = "pinv"
) -> tuple[np.ndarray, np.ndarray]:
    """``uio_matrices`` at each row of ``gammas`` (K, m), with their C̄_γ (K, m, n + q): Q (K, n + q, m)
    and T (K, n + q, n + q), each run's bit for bit (the products stacked, the pseudoinverse run by
    run); one that LAPACK cannot factor raises."""
    Ebar = model.Ebar
    if form == "pinv":
        Q = np.matmul(Ebar, pseudo_inverses(np.matmul(Cbars, Ebar)))
    elif form == "lft":
        Q = model.Ebar_G_pinv / gammas[:, None, :]
    else:
        raise ValueError(f"unknown form {form!r}; use 'pinv' or 'lft'")
    T = -np.matmul(Q, Cbars)
    diagonal = np.arange(T.shape[1])
    T[:, diagonal, diagonal] += 1.0  # I − Q C̄, without building I
    return Q, T


def pseudo_inverse(M: np.ndarray) -> np.ndarray:
    """The Moore–Penrose inverse M⁺ = V Σ⁺ Uᵀ of M (k, l), as np.linalg.pinv (singular values below
    1e-15 σ_max taken as zero), from LAPACK's SVD directly: the reconciliators form one every tick,
    and numpy.linalg's checks cost more than the SVD of a 4 × 1 matrix."""
    u, s, vt, info = lapack.dgesdd(M, compute_uv=1, full_matrices=0)
    if info != 0:
        raise np.linalg.LinAlgError(f"SVD did not converge (LAPACK dgesdd info {info})")
    # LAPACK sorts s in decreasing order: s[0] is σ_max, s[-1] σ_min (usually above the cut: then no mask)
    if len(s) and s[-1] > 1e-15 * s[0]:
        inverse = 1.0 / s
    else:
        inverse = np.divide(1.0, s, out=np.zeros_like(s), where=s > 1e-15 * s[0]) if len(s) else s
    return vt.T.dot(inverse[:, None] * u.T)


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
    lam = ((np.asarray(gamma, dtype=float) - lower) / (np.asarray(upper) - lower)).tolist()
    # ρ_v = Π_j (λ_j if bit j of v is set else 1 − λ_j), built up one coordinate at a time (bit j
    # the j-th least significant), in plain floats: the reconciliators evaluate it every tick.
    weights = [1.0]
    for value in lam:
        value = min(max(value, 0.0), 1.0)
        weights = [w * factor for factor in (1.0 - value, value) for w in weights]
    return np.array(weights)


def box_coordinates_runs(gammas: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """``box_coordinates`` of each row of ``gammas`` (K, m), shape (K, 2^m): each ρ_v the same
    product in the same order, ((f_0 f_1) f_2) …, f_j = λ_j or 1 − λ_j by bit j of v, on arrays; each
    run's bit for bit."""
    lam = np.minimum(np.maximum((np.asarray(gammas, dtype=float) - lower) / (np.asarray(upper) - lower), 0.0), 1.0)
    factors = np.stack((1.0 - lam, lam), axis=2)  # (K, m, 2): by coordinate, then bit
    bits = _vertex_bits(lam.shape[1])
    weights = factors[:, 0, bits[0]]
    for j in range(1, lam.shape[1]):
        weights = weights * factors[:, j, bits[j]]
    return weights


@functools.lru_cache(maxsize=8)
def _vertex_bits(m: int) -> np.ndarray:
    """Bit j of each vertex index v = 0 … 2^m − 1, shape (m, 2^m)."""
    return (np.arange(2**m)[None, :] >> np.arange(m)[:, None]) & 1


def pseudo_inverses(Ms: np.ndarray) -> np.ndarray:
    """``pseudo_inverse`` of each matrix of a stack (K, k, l), each bit for bit: LAPACK's SVD run by
    run, the products on the stack (each factor held as the single call has it: Vᵀ's transpose, a
    C-ordered view of LAPACK's Fortran array, copied in C order); a matrix with a singular value
    below the cut by ``pseudo_inverse`` itself."""
    found = [lapack.dgesdd(M, compute_uv=1, full_matrices=0) for M in Ms]
    if any(info != 0 for *_, info in found):
        bad = next(info for *_, info in found if info != 0)
        raise np.linalg.LinAlgError(f"SVD did not converge (LAPACK dgesdd info {bad})")
    s = np.stack([f[1] for f in found])
    if not s.shape[1] or not np.all(s[:, -1] > 1e-15 * s[:, 0]):
        return np.stack([pseudo_inverse(M) for M in Ms])
    ut = np.stack([f[0].T for f in found])
    v = np.stack([f[2].T for f in found])
    return np.matmul(v, (1.0 / s)[:, :, None] * ut)


# -- checks ------------------------------------------------------------------------------------


def max_spectral_radius(
    model: SensorFaultModel,
    gain: Callable[[np.ndarray], np.ndarray],
    lower: ArrayLike,
    upper: ArrayLike,
    *,
    form: str = "pinv",
    samples: int = 200,
    seed: int = 0,
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
CLARABEL_OPTIONS = {"chordal_decomposition_enable": False, "tol_gap_abs": 1e-7, "tol_gap_rel": 1e-7, "tol_feas": 1e-7}
INFEASIBLE = "the LMIs are {status}; the design has no solution on this Γ (narrow Γ or check the model)"


def solve_problem(problem: cp.Problem, solver: str, what: str) -> None:
    import cvxpy as cp

    options = CLARABEL_OPTIONS if solver == "CLARABEL" else {}
    try:
        problem.solve(solver=solver, **options)
    except cp.error.SolverError as error:
        raise DesignError(f'{what}: the SDP solver {solver} failed ({error}); try solver = "SCS"') from None
    if problem.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
        raise DesignError(f"{what}: {INFEASIBLE.format(status=problem.status)}")


def solved_value(value: np.ndarray | None, what: str) -> np.ndarray:
    """A variable's value after ``solve_problem`` returned (an optimal status sets every variable; cvxpy
    types ``value`` optional, None before a solve)."""
    if value is None:
        raise DesignError(f"{what}: the SDP solver reported a solution but left a variable without a value")
    return value


def check_certificate(min_eig: float, margin: float, what: str) -> None:
    # The solver's tolerance may leave the constraint margin slightly violated; a negative
    # eigenvalue beyond it means the certificate is invalid.
    if min_eig < -1e-7:
        raise DesignError(f"{what}: the solution violates the LMI (smallest eigenvalue {min_eig:.3g} < 0)")
