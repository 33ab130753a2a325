"""The ODE (6)–(7) of the continuous-time adaptive observer of CDC 2016 (``estimators.continuous``)
with its Jacobian in closed form: ``ObserverODE`` for one run, in Python floats between two matrix
products, and ``ObserverODERuns`` for K runs at once, each run bit for bit its ``ObserverODE``.
"""

from __future__ import annotations

import functools
import itertools
import math
import operator
from collections.abc import Sequence

import numpy as np

from estimators.batched import mv

_ADJUGATE = np.array([3, 1, 2, 0])  # R⁻¹ = [r22, −r12; −r21, r11] / det R, row by row
_TWICE = np.array([0, 1, 0, 1])


def _solve_twice(R: list[float], b: list[float], c: list[float]) -> tuple[list[float], list[float], list[float], float]:
    """z = R⁻¹ b, R⁻¹ (z − c), R⁻¹ (row by row) and det R, for the q×q matrix R given row by row; in
    closed form, in Python floats, for the usual q ≤ 2 (a LAPACK call costs more than the whole formula
    there). A singular R gives NaN, as LAPACK's inf or NaN would: the step-size control rejects the step."""
    if len(b) == 2:
        r11, r12, r21, r22 = R
        det = r11 * r22 - r12 * r21
        k = 1.0 / det if det else math.nan
        inverse = [r22 * k, -r12 * k, -r21 * k, r11 * k]
        i11, i12, i21, i22 = inverse
        z1, z2 = i11 * b[0] + i12 * b[1], i21 * b[0] + i22 * b[1]
        e1, e2 = z1 - c[0], z2 - c[1]
        return [z1, z2], [i11 * e1 + i12 * e2, i21 * e1 + i22 * e2], inverse, det
    if len(b) == 1:
        det = R[0]
        k = 1.0 / det if det else math.nan
        return [b[0] * k], [(b[0] * k - c[0]) * k], [k], det
    M = np.array(R).reshape(len(b), len(b))
    M_inv = np.linalg.inv(M)
    z = M_inv.dot(b)
    return z.tolist(), M_inv.dot(z - c).tolist(), M_inv.ravel().tolist(), float(np.linalg.det(M))


class ObserverODE:
    """dw/dt = f(w) of eq. (6)–(7) for w = [x̂; Γ], with the sample's y and u held (``hold``), and its
    Jacobian ∂f/∂w in closed form (``linearized``).

    With e = Z_Γ y − H x̂, r = y − Y Z_Γ y, s = Y R⁻¹ e, R = Yᵀ G_Γ Y, P = Y R⁻¹ Yᵀ and g = 2 r∘s the
    gradient (8): R Z_Γ y = Yᵀ G_Γ y gives ∂(Z_Γ y)/∂Γ = R⁻¹ Yᵀ diag(r), so

        ∂ẋ̂/∂x̂ = A − L H,  ∂ẋ̂/∂Γ = L R⁻¹ Yᵀ diag(r),  ∂g/∂x̂ = −2 diag(r) Y R⁻¹ H,
        ∂g/∂Γ = 2 (diag(r) Y R⁻² Yᵀ diag(r) − diag(s) P diag(r) − diag(r) P diag(s)),
        ∂|det R|/∂Γ_j = |det R| P_jj,  ∂(κ_Γ (1 − |Γ|²) Γ)/∂Γ = κ_Γ ((1 − |Γ|²) I − 2 Γ Γᵀ).

    With vectors of a few entries numpy's cost is its calls, not its arithmetic: f is two matrix
    products, and Python floats between them. R = Σ_j Γ_j Y_jᵀ Y_j (Y_j the rows of Y: R row by row
    is ``K`` Γ) and Yᵀ G_Γ y = Yᵀ diag(y) Γ are linear in w, so ``front`` w = [R row by row; Yᵀ G_Γ y;
    H x̂]. Then R Z_Γ y = Yᵀ G_Γ y and R m = e (so s = Y m) are solved in closed form, and the rest
    is linear in v = [Z_Γ y; m; 1; w; R⁻¹ row by row]: ``back`` v = [dx̂/dt; r; s; diag(r) Y;
    diag(s) Y; diag P; −2 κ_Γ Γ], the matrices row by row, y and B u entering by the column of the 1.
    """

    def __init__(
        self,
        A: np.ndarray,
        B: np.ndarray,
        H: np.ndarray,
        L: np.ndarray,
        Y: np.ndarray,
        kappa_phi: float,
        kappa_gamma: float,
    ) -> None:
        p, q = Y.shape
        n = A.shape[0]
        self.n, self.p, self.q = n, p, q
        self.B, self.H, self.L, self.Y = B, H, L, Y
        self.A_LH = A - L @ H
        self.kappa_phi, self.kappa_gamma = kappa_phi, kappa_gamma
        self.K = np.einsum("ja,jb->abj", Y, Y).reshape(q * q, p)
        self.front = np.zeros((q * q + 2 * q, n + p))  # the rows of Yᵀ diag(y) are set by ``hold``
        self.front[: q * q, n:] = self.K
        self.front[q * q + q :, :n] = H
        # back's rows (its product's parts) and columns (the parts of v)
        ends = list(itertools.accumulate((n, p, p, p * q, p * q, p, p)))
        self.dx_rows, self.r_rows, self.s_rows, self.rY_rows, self.sY_rows, self.P_rows, self.gamma_rows = (
            slice(a, b) for a, b in zip([0, *ends], ends)
        )
        z, m, self.one_column = slice(0, q), slice(q, 2 * q), 2 * q  # the column of the 1 is set by ``hold``
        x, gamma, R_inv = slice(2 * q + 1, 2 * q + 1 + n), slice(2 * q + 1 + n, 2 * q + 1 + n + p), slice(-q * q, None)
        self.back = np.zeros((ends[-1], 2 * q + 1 + n + p + q * q))
        self.back[self.dx_rows, z], self.back[self.dx_rows, x] = L, self.A_LH
        self.back[self.r_rows, z] = -Y
        self.back[self.s_rows, m] = Y
        YY = np.einsum("ia,ib->iab", Y, Y).reshape(p * q, q)
        self.back[self.rY_rows, z] = -YY  # r_i Y_ia = y_i Y_ia − Σ_b Y_ia Y_ib (Z_Γ y)_b
        self.back[self.sY_rows, m] = YY
        self.back[self.P_rows, R_inv] = self.K.T  # P_jj = Σ_ab Y_ja Y_jb (R⁻¹)_ab
        self.back[self.gamma_rows, gamma] = -2.0 * kappa_gamma * np.eye(p)
        self.identity = np.eye(n + p)
        self.identity_p = np.eye(p)

    def hold(self, y: np.ndarray, u: np.ndarray) -> None:
        """The readings and inputs held until the next sample."""
        n, q = self.n, self.q
        self.Bu = self.B.dot(u)
        self.front[q * q : q * q + q, n:] = self.Y.T * y
        one = self.back[:, self.one_column]
        one[self.dx_rows] = self.Bu
        one[self.r_rows] = y
        one[self.rY_rows] = (self.Y * y[:, None]).ravel()

    def _evaluate(
        self, w: np.ndarray
    ) -> tuple[np.ndarray, list[float], float, np.ndarray, list[float], list[float], float]:
        """f(w); and on the way R⁻¹ (row by row), det R, ``back`` v, −κ_φ |det R| g, Γ and κ_Γ (1 − |Γ|²)."""
        n, q = self.n, self.q
        front = self.front.dot(w).tolist()
        Zy, m, R_inv, det = _solve_twice(front[: q * q], front[q * q : q * q + q], front[q * q + q :])
        w_list = w.tolist()
        back = self.back.dot(np.array(Zy + m + [1.0] + w_list + R_inv))
        values = back[: self.s_rows.stop].tolist()
        gamma = w_list[n:]
        rate = -2.0 * self.kappa_phi * abs(det)
        descent = [rate * ri * si for ri, si in zip(values[self.r_rows], values[self.s_rows])]
        shrink = self.kappa_gamma * (1.0 - functools.reduce(operator.add, map(operator.mul, gamma, gamma)))
        f = np.array(values[self.dx_rows] + [d + shrink * c for d, c in zip(descent, gamma)])
        return f, R_inv, det, back, descent, gamma, shrink

    def __call__(self, w: np.ndarray) -> np.ndarray:
        return self._evaluate(w)[0]

    def linearized(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """f(w) and ∂f/∂w."""
        n, p, q = self.n, self.p, self.q
        f, R_inv, det, back, descent, gamma, shrink = self._evaluate(w)
        rYR = back[self.rY_rows].reshape(p, q).dot(np.array(R_inv).reshape(q, q))  # diag(r) Y R⁻¹
        rYR_rate = rYR * (2.0 * self.kappa_phi * abs(det))
        sY = back[self.sY_rows].reshape(p, q)  # diag(s) Y
        J = np.empty((n + p, n + p))
        J[:n, :n] = self.A_LH
        J[:n, n:] = self.L.dot(rYR.T)
        J[n:, :n] = rYR_rate.dot(self.H)
        # R⁻¹ being symmetric, diag(r) Y R⁻² Yᵀ diag(r) = rYR rYRᵀ and diag(r) P diag(s) = rYR sYᵀ; and
        # −κ_φ |det R| g diag(P)ᵀ − 2 κ_Γ Γ Γᵀ is one product (the rows of diag P and −2 κ_Γ Γ are adjacent)
        rank_two = np.array([descent, gamma]).T.dot(back[self.P_rows.start : self.gamma_rows.stop].reshape(2, p))
        J[n:, n:] = rYR_rate.dot((sY - rYR).T) + sY.dot(rYR_rate.T) + rank_two + shrink * self.identity_p
        return f, J

    def weight_det(self, gamma: np.ndarray) -> float:
        """det R = det(Yᵀ G_Γ Y)."""
        R = self.K.dot(gamma)
        if self.q == 2:
            r11, r12, r21, r22 = R.tolist()
            return r11 * r22 - r12 * r21
        return float(np.linalg.det(R.reshape(self.q, self.q)))


class ObserverODERuns:
    """``ObserverODE`` of K runs at once, each with its own held readings and inputs: f and ∂f/∂w of
    w (k, n + p) for the runs ``rows`` of the K (sorted), each row bit for bit its run's ``ObserverODE``.
    Each run may have a design of its own (its gain L and learning rates κ_φ, κ_Γ: the estimators of
    one scenario that differ only in them step together); A, B, H and Y are the runs' one model's.

    Each run has its own ``front`` and ``back`` (their rows of y and B u are its own), multiplied by
    NumPy's stacked products, which call the one-run ``dot``'s kernel per run; the closed forms between
    them are elementwise, in the one-run code's order (its Python floats round as NumPy's elementwise
    operations do). The cost is the number of NumPy calls, whatever K: so each formula is one call
    over all its components where the order of operations allows. With q > 2, R⁻¹ is NumPy's
    stacked ``inv``, and a run whose R is singular raises as alone (``raised``: run → what it
    raised; its row NaN)."""

    def __init__(self, odes: Sequence[ObserverODE]) -> None:
        """One ``ObserverODE`` per run (the same object for runs of one design)."""
        ode = self.ode = odes[0]
        runs = len(odes)
        self.identity = ode.identity
        self.front = np.repeat(ode.front[None], runs, axis=0)
        self.back = np.stack([each.back for each in odes])
        self.L = np.stack([each.L for each in odes])
        self.A_LH = np.stack([each.A_LH for each in odes])
        self.kappa_phi = np.array([[each.kappa_phi] for each in odes])
        self.kappa_gamma = np.array([[each.kappa_gamma] for each in odes])
        self.ones = np.ones((runs, 1))
        self.Bu = np.zeros((runs, ode.n))
        self.raised: dict[int, str] = {}

    def hold(self, y: np.ndarray, u: np.ndarray) -> None:
        """Each run's readings and inputs (K, p) and (K, m), held until the next sample."""
        ode, n, q = self.ode, self.ode.n, self.ode.q
        self.Bu = mv(ode.B, u)
        self.front[:, q * q : q * q + q, n:] = ode.Y.T * y[:, None, :]
        one = self.back[:, :, ode.one_column]
        one[:, ode.dx_rows] = self.Bu
        one[:, ode.r_rows] = y
        one[:, ode.rY_rows] = (ode.Y * y[:, :, None]).reshape(len(y), -1)

    def _evaluate(self, w: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, ...]:
        """``ObserverODE._evaluate`` of each row: f, R⁻¹, det R, back v, −κ_φ |det R| g, Γ, κ_Γ (1 − |Γ|²)
        (the runs' scalars as columns, (k, 1))."""
        ode, n = self.ode, self.ode.n
        every = len(rows) == len(self.front)  # then no copy of the runs' matrices
        front = np.matmul(self.front if every else self.front[rows], w[:, :, None])[:, :, 0]
        Zy, m, R_inv, det = self._solve_twice(front, rows)
        v = np.concatenate([Zy, m, self.ones[: len(w)], w, R_inv], axis=1)
        back = np.matmul(self.back if every else self.back[rows], v[:, :, None])[:, :, 0]
        gamma = w[:, n:]
        kappa_phi = self.kappa_phi if every else self.kappa_phi[rows]
        descent = (-2.0 * kappa_phi) * np.abs(det) * back[:, ode.r_rows] * back[:, ode.s_rows]
        squares = gamma * gamma
        total = squares[:, :1]
        for j in range(1, ode.p):  # left to right, as ObserverODE adds them
            total = total + squares[:, j : j + 1]
        shrink = (self.kappa_gamma if every else self.kappa_gamma[rows]) * (1.0 - total)
        f = np.concatenate([back[:, ode.dx_rows], descent + shrink * gamma], axis=1)
        return f, R_inv, det, back, descent, gamma, shrink

    def _solve_twice(self, front: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, ...]:
        """``_solve_twice`` of each row of ``front`` v (R row by row, b, c): R⁻¹ b, R⁻¹ (z − c), R⁻¹, det R."""
        q = self.ode.q
        R, b, c = front[:, : q * q], front[:, q * q : q * q + q], front[:, q * q + q :]
        if q > 2:
            return self._solve_stacked(R, b, c, rows)
        det = R[:, :1] * R[:, 3:] - R[:, 1:2] * R[:, 2:3] if q == 2 else R
        k = 1.0 / det
        np.copyto(k, math.nan, where=det == 0)  # a singular R: NaN, as alone
        if q == 1:
            z = b * k
            return z, (z - c) * k, k, det
        inverse = R.take(_ADJUGATE, axis=1) * k
        np.negative(inverse[:, 1:3], out=inverse[:, 1:3])  # −(r12 k) = (−r12) k, exactly
        products = inverse * b.take(_TWICE, axis=1)  # i11 b1, i12 b2, i21 b1, i22 b2
        z = products[:, 0::2] + products[:, 1::2]
        products = inverse * (z - c).take(_TWICE, axis=1)
        return z, products[:, 0::2] + products[:, 1::2], inverse, det

    def _solve_stacked(self, R: np.ndarray, b: np.ndarray, c: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, ...]:
        """``_solve_twice`` for q > 2, by NumPy's stacked ``inv`` and ``det``; run by run where an R is singular."""
        q = b.shape[1]
        M = R.reshape(len(R), q, q)
        try:
            M_inv = np.linalg.inv(M)
        except np.linalg.LinAlgError:  # some run's R is singular: each by itself, as alone
            return self._solve_each(R, b, c, rows)
        z = mv(M_inv, b)
        return z, mv(M_inv, z - c), M_inv.reshape(len(R), q * q), np.linalg.det(M)[:, None]

    def _solve_each(self, R: np.ndarray, b: np.ndarray, c: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, ...]:
        """``_solve_twice`` run by run; a run where it raises is in ``raised``, its row NaN."""
        z, second, inverse = np.full_like(b, math.nan), np.full_like(b, math.nan), np.full_like(R, math.nan)
        det = np.full((len(R), 1), math.nan)
        for i, run in enumerate(rows.tolist()):
            try:
                z[i], second[i], inverse[i], det[i] = _solve_twice(R[i].tolist(), b[i].tolist(), c[i])
            except np.linalg.LinAlgError as error:
                self.raised.setdefault(run, f"LinAlgError: {error}")  # (the first, as alone)
        return z, second, inverse, det

    def __call__(self, w: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return self._evaluate(w, rows)[0]

    def linearized(self, w: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """f(w) and ∂f/∂w of each row, (k, n + p) and (k, n + p, n + p)."""
        ode, n, p, q = self.ode, self.ode.n, self.ode.p, self.ode.q
        f, R_inv, det, back, descent, gamma, shrink = self._evaluate(w, rows)
        k = len(w)
        every = k == len(self.front)
        rYR = np.matmul(back[:, ode.rY_rows].reshape(k, p, q), R_inv.reshape(k, q, q))  # diag(r) Y R⁻¹
        kappa_phi = self.kappa_phi if every else self.kappa_phi[rows]
        rYR_rate = rYR * ((2.0 * kappa_phi) * np.abs(det))[:, :, None]
        sY = back[:, ode.sY_rows].reshape(k, p, q)  # diag(s) Y
        J = np.empty((k, n + p, n + p))
        J[:, :n, :n] = self.A_LH if every else self.A_LH[rows]
        J[:, :n, n:] = np.matmul(self.L if every else self.L[rows], rYR.swapaxes(1, 2))
        J[:, n:, :n] = np.matmul(rYR_rate, ode.H)
        outer = np.stack([descent, gamma], axis=1).swapaxes(1, 2)
        rank_two = np.matmul(outer, back[:, ode.P_rows.start : ode.gamma_rows.stop].reshape(k, 2, p))
        J[:, n:, n:] = (
            np.matmul(rYR_rate, (sY - rYR).swapaxes(1, 2))
            + np.matmul(sY, rYR_rate.swapaxes(1, 2))
            + rank_two
            + shrink[:, :, None] * ode.identity_p
        )
        return f, J

    def weight_det(self, gamma: np.ndarray) -> np.ndarray:
        """``ObserverODE.weight_det`` of each row of Γ (k, p)."""
        q = self.ode.q
        R = mv(self.ode.K, gamma)
        if q == 2:
            return R[:, 0] * R[:, 3] - R[:, 1] * R[:, 2]
        return np.linalg.det(R.reshape(len(R), q, q))
