"""Design utilities shared by the estimators: output factorization, gains, weighted pseudoinverses.

Plain functions on arrays (python-control style). Equation numbers refer to Cristofaro & Zaccarian,
"Adaptive Pseudoinverse Observers for Output Redundant Discrete-Time Linear Systems", IEEE TAC 2024.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np


def output_factorization(C: np.ndarray, tol: float = 1e-10) -> tuple[np.ndarray, np.ndarray]:
    """Factor C = Y H with q = rk(C) = rk(H) and unitary columns YᵀY = I_q (eq. (2), Assumption 2.1).

    Following Example 1 (eq. (3)–(4)): H∘ keeps the first q linearly independent rows of C, Y∘
    expresses every row of C in them (C = Y∘ H∘), and the normalization
    Y = Y∘ (Y∘ᵀY∘)^(−1/2), H = (Y∘ᵀY∘)^(1/2) H∘ makes the columns of Y orthonormal.

    Returns Y with shape (p, q) and H with shape (q, n).
    """
    C = np.asarray(C, dtype=float)
    rows: list[int] = []
    for i in range(C.shape[0]):
        if np.linalg.matrix_rank(C[rows + [i]], tol=tol) > len(rows):
            rows.append(i)
    H0 = C[rows]
    Y0 = np.linalg.solve(H0 @ H0.T, H0 @ C.T).T  # C H0⁺, exact since rows of C lie in rowspace(H0)
    gram = Y0.T @ Y0
    w, V = np.linalg.eigh(gram)
    gram_sqrt = (V * np.sqrt(w)) @ V.T
    gram_inv_sqrt = (V / np.sqrt(w)) @ V.T
    return Y0 @ gram_inv_sqrt, gram_sqrt @ H0


class AssumptionError(ValueError):
    """A standing assumption of the papers fails for this model (the message says which and why)."""


def assumption2_factorization(C: np.ndarray, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Y, H, Σ) with Σ C = Y H satisfying Assumption 2 of TAC 2024 (shapes (p, q), (q, n), (p, p)).

    Starts from ``output_factorization`` (unitary columns, YᵀY = I). If some canonical vector eᵢ
    lies in Im(Y) (a sensor that no other combination of sensors reproduces), the construction
    after Assumption 2 recombines the outputs: Σ is the Householder reflection that maps a unit
    vector of Im(Y)^⊥ onto 𝐧 = p^(−1/2) 𝟙, and Y ← Σ Y. Then Im(Y)^⊥ ∋ 𝐧, which no eᵢ is orthogonal
    to, so no eᵢ lies in Im(Y). Otherwise Σ = I. Both properties are verified before returning.
    """
    C = np.asarray(C, dtype=float)
    p = C.shape[0]
    Y, H = output_factorization(C)
    q = Y.shape[1]
    if q >= p:
        raise AssumptionError(f"outputs are not redundant: rank(C) = {q} is not below p = {p} (Assumption 1.1)")
    sigma = np.eye(p)
    if not _nonaligned(Y, tol):
        complement = np.linalg.svd(Y)[0][:, q]  # a unit vector orthogonal to Im(Y)
        w = complement - np.full(p, 1 / np.sqrt(p))
        if np.linalg.norm(w) > tol:
            sigma = np.eye(p) - 2.0 * np.outer(w, w) / (w @ w)
        Y = sigma @ Y
    if not np.allclose(Y.T @ Y, np.eye(q), atol=1e-12) or not _nonaligned(Y, tol):
        raise AssumptionError("could not construct a selection (Y, H) satisfying Assumption 2")
    if not np.allclose(sigma @ C, Y @ H, atol=1e-10 * max(1.0, np.abs(C).max())):
        raise AssumptionError("Σ C = Y H does not hold")
    return Y, H, sigma


def _nonaligned(Y: np.ndarray, tol: float) -> bool:
    """eᵢ ∉ Im(Y) for every i: with orthonormal columns, |Yᵀeᵢ| = 1 exactly when eᵢ ∈ Im(Y)."""
    return bool(np.max(np.linalg.norm(Y, axis=1)) < 1.0 - tol)


def check_assumption1(A: np.ndarray, C: np.ndarray, *, discrete: bool = True, tol: float = 1e-9) -> None:
    """Assumption 1 of TAC 2024 (and its continuous-time counterpart in CDC 2016, eq. (2) and Assumption 1).

    1. output redundancy q = rk(C) < p;
    2. detectability of (C, A): rank [A − λI; C] = n for every eigenvalue λ with |λ| ≥ 1
       (discrete time) or Re λ ≥ 0 (continuous time), the PBH test;
    3. (discrete time) A − I nonsingular, so that a constant bias is distinguishable from the state.
    Raises AssumptionError naming the item that fails.
    """
    A = np.asarray(A, dtype=float)
    C = np.asarray(C, dtype=float)
    n, p = A.shape[0], C.shape[0]
    q = np.linalg.matrix_rank(C, tol=tol * max(1.0, np.abs(C).max()))
    if q >= p:
        raise AssumptionError(f"outputs are not redundant: rank(C) = {q} is not below p = {p} (Assumption 1.1)")
    for lam in np.linalg.eigvals(A):
        unstable = abs(lam) >= 1.0 - tol if discrete else lam.real >= -tol
        if unstable and np.linalg.matrix_rank(np.vstack([A - lam * np.eye(n), C]), tol=1e-8) < n:
            raise AssumptionError(
                f"(C, A) is not detectable: the mode λ = {lam:.6g} is unstable and unobservable (Assumption 1.2)"
            )
    if discrete and np.min(np.abs(np.linalg.eigvals(A) - 1.0)) < tol:
        raise AssumptionError(
            "A has an eigenvalue at 1, so a constant bias cannot be told from the state (Assumption 1.3)"
        )


def fault_rejectable(Y: np.ndarray, phi: np.ndarray, tol: float = 1e-9) -> bool:
    """False when the bias φ lies in Im(Y): then Π(s) φ = w_φ for every weight s, and no adaptive
    pseudoinverse can remove it (TAC 2024 Remark 4; CDC 2016 Remark 2)."""
    phi = np.asarray(phi, dtype=float)
    if not np.any(phi):
        return True
    residual = phi - Y @ np.linalg.lstsq(Y, phi, rcond=None)[0]
    return bool(np.linalg.norm(residual) > tol * np.linalg.norm(phi))


def warn_if_not_rejectable(Y: np.ndarray, phi: np.ndarray, label: str) -> bool:
    """Issue a RuntimeWarning (and return False) when ``fault_rejectable`` is False."""
    if fault_rejectable(Y, phi):
        return True
    warnings.warn(
        f"{label}: the bias direction {np.round(phi, 6).tolist()} lies in Im(Y); an adaptive pseudoinverse "
        "cannot reject it (TAC 2024 Remark 4)",
        RuntimeWarning,
        stacklevel=2,
    )
    return False


def observer_gain(A: np.ndarray, H: np.ndarray, poles: np.ndarray | Sequence[float], tol: float = 1e-6) -> np.ndarray:
    """A gain L such that the spectrum of A − L H is ``poles`` (a Luenberger design, eq. (5)).

    Placement is done on the dual pair (Aᵀ, Hᵀ). Where every pole's multiplicity is at most
    rk(H), scipy's robust placement (Tits–Yang) is used, as MATLAB's ``place`` would be; a pole
    repeated more often than that (a dead-beat design σ(A − M H) = {0, 0, 0, 0} with q = 2, Remark 1)
    is placed by ``place_repeated``. The achieved characteristic polynomial is checked either way.
    Returns L with shape (n, q).
    """
    A = np.asarray(A, dtype=float)
    H = np.asarray(H, dtype=float)
    poles = np.asarray(poles)
    if poles.shape != (A.shape[0],):
        raise ValueError(f"need {A.shape[0]} poles for a state of dimension {A.shape[0]}, got {poles.size}")
    values, counts = np.unique(np.round(poles.astype(complex), 12), return_counts=True)
    if counts.max() <= np.linalg.matrix_rank(H):
        import scipy.signal  # imported here: it takes a second to import, and only design needs it

        with (
            warnings.catch_warnings()
        ):  # "convergence not reached" concerns robustness only; the spectrum is checked below
            warnings.simplefilter("ignore", UserWarning)
            L = scipy.signal.place_poles(A.T, H.T, poles).gain_matrix.T
    else:
        L = place_repeated(A.T, H.T, poles).T
    check_spectrum(A - L @ H, poles, tol)
    return L


def place_repeated(A: np.ndarray, B: np.ndarray, poles: np.ndarray) -> np.ndarray:
    """A state feedback K with σ(A − B K) = ``poles``, any multiplicities (shapes A (n, n), B (n, m)).

    Luenberger's block companion form: the controllability indices κ₁, …, κ_m of (A, B) split the
    state into m chains; in those coordinates A − B K can be made block diagonal with companion
    blocks of sizes κᵢ, each carrying a chosen polynomial of degree κᵢ. The poles are dealt to the
    blocks (conjugate pairs kept together), so a pole may repeat any number of times, and a
    dead-beat design is nilpotent of index max κᵢ, the fewest steps possible. Raises ValueError if
    (A, B) is not controllable or the poles cannot be dealt into real polynomials of those degrees.
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    n, m = B.shape
    B_eff = B[:, _independent_columns(B)]
    chains: list[list[np.ndarray]] = [[] for _ in range(B_eff.shape[1])]
    basis = np.zeros((n, 0))
    open_chains = set(range(B_eff.shape[1]))
    for power in range(n):
        for i in sorted(open_chains):
            v = np.linalg.matrix_power(A, power) @ B_eff[:, i]
            trial = np.column_stack([basis, v])
            if np.linalg.matrix_rank(trial, tol=1e-10 * max(1.0, float(np.linalg.norm(trial)))) > basis.shape[1]:
                basis = trial
                chains[i].append(v)
            else:
                open_chains.discard(i)
    if basis.shape[1] < n:
        raise ValueError("(A, B) is not controllable: the poles cannot be placed (check detectability of (H, A))")
    sizes = [len(c) for c in chains]
    Q = np.column_stack([v for chain in chains for v in chain])
    Q_inv = np.linalg.inv(Q)
    ends = np.cumsum(sizes)
    rows = []
    for size, end in zip(sizes, ends):
        if size:
            q = Q_inv[end - 1]
            rows += [q @ np.linalg.matrix_power(A, j) for j in range(size)]
    T = np.array(rows)
    T_inv = np.linalg.inv(T)
    A_bar, B_bar = T @ A @ T_inv, T @ B
    lasts = [end - 1 for size, end in zip(sizes, ends) if size]
    desired = np.zeros((len(lasts), n))
    for block, (size, polynomial) in enumerate(zip([s for s in sizes if s], _deal(poles, [s for s in sizes if s]))):
        first = lasts[block] - size + 1
        desired[block, first : first + size] = -polynomial[1:][::-1]
    K_bar = np.linalg.lstsq(B_bar[lasts], A_bar[lasts] - desired, rcond=None)[0]
    return K_bar @ T


def _independent_columns(B: np.ndarray) -> list[int]:
    keep: list[int] = []
    for j in range(B.shape[1]):
        if np.linalg.matrix_rank(B[:, keep + [j]]) > len(keep):
            keep.append(j)
    return keep


def _deal(poles: np.ndarray, sizes: list[int]) -> list[np.ndarray]:
    """Split the poles into real monic polynomials of the given degrees (conjugate pairs together)."""
    poles = np.asarray(poles, dtype=complex)
    real = sorted(p.real for p in poles if abs(p.imag) < 1e-12)
    pairs = sorted(p for p in poles if p.imag >= 1e-12)
    if len(real) + 2 * len(pairs) != len(poles):
        raise ValueError("complex poles must come in conjugate pairs")
    groups: list[list[complex]] = []
    for size in sizes:
        group: list[complex] = []
        while len(group) < size:
            need = size - len(group)
            if real and (need % 2 == 1 or not pairs):
                group.append(real.pop())
            elif pairs and need >= 2:
                p = pairs.pop()
                group += [p, p.conjugate()]
            else:
                raise ValueError(f"cannot split the poles into real polynomials of degrees {sizes}")
        groups.append(group)
    return [np.real(np.poly(group)) for group in groups]


def check_spectrum(closed_loop: np.ndarray, poles: np.ndarray, tol: float = 1e-6) -> None:
    """Raise ValueError unless the characteristic polynomial of ``closed_loop`` has the roots ``poles``.

    Coefficients are compared rather than eigenvalues, which a repeated root makes ill-conditioned
    (a k-fold root moves by ε^(1/k) under a perturbation ε of the matrix).
    """
    achieved = np.poly(closed_loop)
    wanted = np.real_if_close(np.poly(np.asarray(poles)))
    scale = np.maximum(1.0, np.abs(wanted))
    if not np.all(np.abs(achieved - wanted) <= tol * scale):
        raise ValueError(
            f"pole placement missed: wanted {np.sort_complex(np.asarray(poles, dtype=complex))}, got "
            f"{np.sort_complex(np.linalg.eigvals(closed_loop))}"
        )


def weighted_pseudoinverse(Y: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Π(s) = R(s)⁻¹ Γ(s) with R(s) = Yᵀ diag(s) Y and Γ(s) = Yᵀ diag(s) (eq. (14)); shape (q, p)."""
    gamma = Y.T * s
    return np.linalg.solve(gamma @ Y, gamma)


def is_schur(A: np.ndarray) -> bool:
    """All eigenvalues strictly inside the unit circle."""
    return bool(np.max(np.abs(np.linalg.eigvals(A))) < 1.0)


def zoh_discretize(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretization: A_d = exp(A dt), B_d = ∫₀^dt exp(A s) ds B.

    Computed as one matrix exponential of the block matrix [[A, B], [0, 0]] dt (Van Loan).
    """
    n, m = B.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = A
    block[:n, n:] = B
    import scipy.linalg  # here: a node that never discretizes does not pay for importing it

    E = scipy.linalg.expm(block * dt)
    return E[:n, :n], E[:n, n:]
