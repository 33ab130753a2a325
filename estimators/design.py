"""Design utilities shared by the estimators: output factorization, gains, weighted pseudoinverses.

Plain functions on arrays (python-control style). Equation numbers refer to Cristofaro & Zaccarian,
"Adaptive Pseudoinverse Observers for Output Redundant Discrete-Time Linear Systems", IEEE TAC 2024.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg


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


def observer_gain(A: np.ndarray, H: np.ndarray, poles: np.ndarray | list[float], tol: float = 1e-6) -> np.ndarray:
    """A gain L such that the spectrum of A − L H is ``poles`` (a Luenberger design, eq. (5)).

    Placement is done on the dual pair (Aᵀ, Hᵀ); the achieved spectrum is checked.
    Returns L with shape (n, q).
    """
    import scipy.signal  # imported here: it takes a second or two to import, and only design needs it

    A = np.asarray(A, dtype=float)
    H = np.asarray(H, dtype=float)
    poles = np.asarray(poles)
    if poles.shape != (A.shape[0],):
        raise ValueError(f"need {A.shape[0]} poles for a state of dimension {A.shape[0]}, got {poles.size}")
    L = scipy.signal.place_poles(A.T, H.T, poles).gain_matrix.T
    achieved = np.sort_complex(np.linalg.eigvals(A - L @ H))
    if not np.allclose(achieved, np.sort_complex(poles.astype(complex)), atol=tol):
        raise ValueError(f"pole placement missed: wanted {np.sort_complex(poles)}, got {achieved}")
    return L


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
    E = scipy.linalg.expm(block * dt)
    return E[:n, :n], E[:n, n:]
