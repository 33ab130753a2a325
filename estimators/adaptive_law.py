"""The adaptation law of TAC 2024's adaptive pseudoinverse observer: the optimizer G_z (36)–(37e),
the selector (17)/(52) and Algorithm 1's scaling and filtering of φ̂, each for one run and for K
runs at once.

The K-run forms (``optimizer_steps``, ``select_runs``, ``scale_and_filter_runs``: arrays with a
leading run axis, the data-dependent branches as masks) give, row for row, bit for bit what the
one-run forms give: the same IEEE operations in the same order, the products and norms by the
stacked kernels of ``estimators.batched``, the column sums of squares by the same ``einsum`` with a
run index (``tests/test_batched_steps.py`` holds the two forms against each other on inputs that
take every branch). The one-run optimizer keeps its loop over Python floats: on one run it is about
three times quicker than the array form.
"""

from __future__ import annotations

import numpy as np

from estimators.batched import mv, norms

# -- the optimizer G_z (Section V) -------------------------------------------------------------


def cost_matrix(Y: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """S(φ) = Γ(φ)ᵀ Γ(φ) with Γ(φ) = Yᵀ diag(φ) (eq. (14), (36a)); shape (p, p)."""
    gamma = Y.T * phi
    return gamma.T @ gamma


def line_search_coefficients(z: np.ndarray, S: np.ndarray, i: int) -> tuple[float, float, float]:
    """β₀, β₁, β₂ of eq. (37a)–(37c) for the search direction eᵢ (S symmetric).

    β₀ = eᵢᵀ(I − z zᵀ) S z,  β₁ = eᵢᵀ S eᵢ − zᵀ S z,  β₂ = zᵀ(eᵢ eᵢᵀ − I) S eᵢ.
    For f(ζ) = 𝔷ᵀ S 𝔷 with 𝔷 = (z + ζ eᵢ)/|z + ζ eᵢ|, differentiating gives
    f′(ζ) = 2 (β₂ ζ² + β₁ ζ + β₀) / |z + ζ eᵢ|⁴, not (β₂ζ² + 2β₁ζ + β₀)/|·|⁴ as eq. (39) prints
    (erratum, docs/errata.md): (39)–(41) and (37d) hold with β₁ replaced by β₁/2.
    """
    Sz = S @ z
    zSz = z @ Sz
    return Sz[i] - z[i] * zSz, S[i, i] - zSz, z[i] * S[i, i] - Sz[i]


def line_search_step(beta0: float, beta1: float, beta2: float) -> float:
    """The minimizing step ζ of (36) along eᵢ: eq. (37d), (40)–(41) with β₁/2 for β₁ (see above);
    ±inf stands for the candidate ±eᵢ.

    With b = β₁/2 and γ = b² − β₂β₀ ≥ 0, the minimizer is ζ₊ = (√γ − b)/β₂ (the right root of
    f′ for β₂ > 0, the left one for β₂ < 0). For b > 0 it is evaluated as the equal −β₀/(√γ + b),
    which has no cancellation and tends, as β₂ → 0, to the middle case ζ = −β₀/(2b) = −β₀/β₁ of
    (37d); β₂ = 0 and b ≤ 0 give the third case, ±eᵢ.
    """
    b = 0.5 * beta1
    root = np.sqrt(max(b * b - beta2 * beta0, 0.0))  # γ ≥ 0: f′ always changes sign; clip rounding
    if b > 0:
        return -beta0 / (root + b)
    if beta2 != 0:
        return (root - b) / beta2
    return np.inf


def line_search(z: np.ndarray, S: np.ndarray, i: int) -> np.ndarray:
    """A minimizer of (36) along eᵢ: one element of G*ᵢ(z, φ) of eq. (37d) (for ±eᵢ, the one on z's side)."""
    zeta = line_search_step(*line_search_coefficients(z, S, i))
    if np.isinf(zeta):
        return np.where(np.arange(z.size) == i, 1.0 if z[i] >= 0 else -1.0, 0.0)
    candidate = z.copy()
    candidate[i] += zeta
    return candidate / np.linalg.norm(candidate)


def optimizer_step(z: np.ndarray, phi: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """z⁺ ∈ G_z(z, φ) of eq. (37e): the best of the p line-search minimizers G*ᵢ(z, φ).

    O(p) once S z is known (Remark 2): the cost of each candidate follows from (36b) in closed form,
    f(ζ) = (zᵀSz + 2ζ (Sz)ᵢ + ζ² Sᵢᵢ) / (1 + 2ζ zᵢ + ζ²). Ties go to the lowest i. When the cost is
    already zero (z ∈ 𝒵*, for instance φ = 0) z is kept: 𝒵* is forward invariant (Proposition 2).
    """
    gamma = Y.T * phi  # Γ(φ); S = ΓᵀΓ is never formed, which keeps |Γ z|² accurate near zero
    gz = gamma @ z
    zSz = float(gz @ gz)
    S_diag = np.einsum("ij,ij->j", gamma, gamma)
    if zSz <= 1e-28 * max(S_diag.sum(), np.finfo(float).tiny):
        return z
    best_i, best_cost, best_zeta = -1, np.inf, 0.0
    values = z.tolist()
    along = _axis(values)
    # the p candidates in Python floats: the same IEEE arithmetic, without numpy's per-scalar cost
    for i, (zi, Szi, Sii) in enumerate(zip(values, (gamma.T @ gz).tolist(), S_diag.tolist())):
        beta0, beta1, beta2 = Szi - zi * zSz, Sii - zSz, zi * Sii - Szi
        zeta = line_search_step(beta0, beta1, beta2)
        if i == along:  # z = ±eᵢ: the search along eᵢ does not leave it (ζ = 0, its cost zᵀSz)
            zeta, cost = 0.0, zSz
        elif np.isinf(zeta):
            cost = Sii
        else:
            cost = (zSz + 2 * zeta * Szi + zeta * zeta * Sii) / (1 + 2 * zeta * zi + zeta * zeta)
        if cost < best_cost:
            best_i, best_cost, best_zeta = i, cost, zeta
    if np.isinf(best_zeta):
        return np.where(np.arange(z.size) == best_i, 1.0 if z[best_i] >= 0 else -1.0, 0.0)
    candidate = z.copy()
    candidate[best_i] += best_zeta
    return candidate / np.linalg.norm(candidate)


def _axis(z: list[float]) -> int:
    """i where z = ±eᵢ, else −1. The line search along eᵢ then has β₀ = β₁ = β₂ = 0 but for
    rounding, and their quotients pick any ζ: ζ ≈ −1 would give z + ζ eᵢ ≈ 0, and a NaN z."""
    nonzero = [i for i, v in enumerate(z) if v != 0.0]
    return nonzero[0] if len(nonzero) == 1 else -1


# -- the selector (17), (52) --------------------------------------------------------------------


def select(s: np.ndarray, z: np.ndarray, Y: np.ndarray, epsilon: float) -> tuple[np.ndarray, int]:
    """(s⁺, h⁺) of the logic-enhanced selector (52); s⁺ alone is the selector (17).

    s takes z when z is in the interior of 𝒮_ε = {|det R(z)| ≥ ε} (15), with h = 0; otherwise s is
    held and h = 1. On the boundary |det R(z)| = ε, where (52) allows both, s is held.
    """
    if abs(np.linalg.det((Y.T * z) @ Y)) > epsilon:
        return z, 0
    return s, 1


def scale_and_filter(phi_hat: np.ndarray, filtered: np.ndarray, tau: float, eps_phi: float) -> np.ndarray:
    """One step of Algorithm 1: φ̂* = φ̂ / max(|φ̂|, ε_φ) (i), φ̂** ← (1 − τ) φ̂** + τ φ̂* (ii)."""
    scaled = phi_hat / max(np.linalg.norm(phi_hat), eps_phi)
    return (1.0 - tau) * filtered + tau * scaled


# -- K runs at once -----------------------------------------------------------------------------


def optimizer_steps(z: np.ndarray, phi: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """``optimizer_step`` of each run: z and φ of shape (K, p), z⁺ of shape (K, p)."""
    gamma = Y.T * phi[:, None, :]  # each Γ(φ) laid out as the one-run product lays it out
    gz = mv(gamma, z)
    zSz = np.matmul(gz[:, None, :], gz[:, :, None])[:, 0, 0]
    S_diag = np.einsum("kij,kij->kj", gamma, gamma)
    total, tiny = S_diag.sum(axis=1), np.finfo(float).tiny
    settled = zSz <= 1e-28 * np.where(tiny > total, tiny, total)  # Python's max(total, tiny)
    zeta, cost = _candidates(z, mv(gamma.transpose(0, 2, 1), gz), S_diag, zSz[:, None])
    along = (z != 0.0) & ((z != 0.0).sum(axis=1) == 1)[:, None]  # z = ±eᵢ: ``_axis``
    zeta, cost = np.where(along, 0.0, zeta), np.where(along, zSz[:, None], cost)
    eligible = cost < np.inf  # as the loop's cost < best_cost from inf: never NaN, never inf
    found = eligible.any(axis=1)
    rows = np.arange(len(z))
    best = np.where(found, np.argmin(np.where(eligible, cost, np.inf), axis=1), z.shape[1] - 1)  # ties: lowest i
    step = np.where(found, zeta[rows, best], 0.0)  # none found: the loop's z[-1] += 0.0
    candidate = z.copy()
    candidate[rows, best] += step
    with np.errstate(divide="ignore", invalid="ignore"):
        moved = candidate / norms(candidate)[:, None]
    sign = np.where(z[rows, best] >= 0, 1.0, -1.0)[:, None]
    corner = np.where(np.arange(z.shape[1]) == best[:, None], sign, 0.0)  # the candidate ±eᵢ
    return np.where(settled[:, None], z, np.where(np.isinf(step)[:, None], corner, moved))


def _candidates(z: np.ndarray, Sz: np.ndarray, S_diag: np.ndarray, zSz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each run's p steps ζ of ``line_search_step`` and the costs f(ζ) of ``optimizer_step``, (K, p)
    each; ±inf for the candidate ±eᵢ, whose cost is Sᵢᵢ."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        beta0, beta1, beta2 = Sz - z * zSz, S_diag - zSz, z * S_diag - Sz
        b = 0.5 * beta1
        gamma = b * b - beta2 * beta0
        root = np.sqrt(np.where(0.0 > gamma, 0.0, gamma))  # Python's max(γ, 0.0), −0.0 and NaN kept
        zeta = np.where(b > 0, -beta0 / (root + b), np.where(beta2 != 0, (root - b) / beta2, np.inf))
        cost = (zSz + 2 * zeta * Sz + zeta * zeta * S_diag) / (1 + 2 * zeta * z + zeta * zeta)
    return zeta, np.where(np.isinf(zeta), S_diag, cost)


def select_runs(s: np.ndarray, z: np.ndarray, Y: np.ndarray, epsilon: float) -> tuple[np.ndarray, np.ndarray]:
    """``select`` of each run: s and z of shape (K, p); s⁺ (K, p) and h⁺ (K,) as integers."""
    taken = np.abs(np.linalg.det((Y.T * z[:, None, :]) @ Y)) > epsilon
    return np.where(taken[:, None], z, s), (~taken).astype(int)


def scale_and_filter_runs(phi_hat: np.ndarray, filtered: np.ndarray, tau: float, eps_phi: float) -> np.ndarray:
    """``scale_and_filter`` of each run: φ̂ and φ̂** of shape (K, p)."""
    size = norms(phi_hat)
    scaled = phi_hat / np.where(eps_phi > size, eps_phi, size)[:, None]  # Python's max(|φ̂|, ε_φ)
    return (1.0 - tau) * filtered + tau * scaled
