"""Theorem 1 of IJC 2018 (estimators.lpv_design): the direct conic assembly for Clarabel against the LMIs
(19)–(20) as printed and against the cvxpy reference."""

from __future__ import annotations

import numpy as np
import pytest

from estimators.lmi import MARGIN, DesignError, SensorFaultModel, box_vertices, max_spectral_radius, uio_matrices
from estimators.lpv_design import lpv_uio_design, theorem1_conic_data, theorem1_lmis
from mjcf.three_tank import PAPER_A, PAPER_B, PAPER_C, PAPER_E

# A 2-state plant with 3 sensors: 8 vertices, 64 + 224 LMIs (19)–(20) of size 10 (also tests/test_reconciliation.py).
SMALL = SensorFaultModel(
    np.array([[0.95, 0.05], [0.0, 0.9]]),
    np.eye(2),
    np.array([[1.0], [0.5]]),
    np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]),
    np.ones((3, 1)),
)
THREE_TANK = SensorFaultModel(PAPER_A, PAPER_B, PAPER_E, PAPER_C, np.ones((4, 1)))


def vertex_matrices(model, lower, upper):
    """T̃_i Ā, C̃_i and F_i = [T̃_i F̄, I] at the corners of the box (Remark 2)."""
    Ts = np.array([uio_matrices(model, g)[1] for g in box_vertices(lower, upper)])
    Cs = np.array([model.Cbar(g) for g in box_vertices(lower, upper)])
    Fs = np.array([np.hstack([T @ model.Fbar, np.eye(len(T))]) for T in Ts])
    return Ts @ model.Abar, Cs, Fs


def svec(M):
    """Clarabel's triangle form: upper triangle by columns, off-diagonal entries times √2."""
    n = len(M)
    return np.array([M[i, j] * (1.0 if i == j else np.sqrt(2.0)) for j in range(n) for i in range(j + 1)])


def test_the_conic_data_are_the_printed_lmis_with_s_in_place_of_p_j():
    """With every S_ik set to P_j, the cones of the size of Ξ hold exactly Ξ_ij (19) and Ξ_ijk (20)
    minus margin·I, and the small cones hold P_j − P_j' for every j'."""
    TA, C, F = vertex_matrices(SMALL, np.full(3, 0.5), np.ones(3))
    l, nx, nw = F.shape
    cost, A, b, sizes, layout = theorem1_conic_data(TA, C, F)
    pairs = l * (l + 1) // 2
    assert sizes == [2 * nx + nw] * pairs + [nx] * (pairs * l)
    rng = np.random.default_rng(1)
    P = rng.normal(size=(l, nx, nx))
    P = P + P.transpose(0, 2, 1)
    G, Y, mu = rng.normal(size=(l, nx, nx)), rng.normal(size=(l, nx, 3)), 0.7
    j = 5
    x = np.concatenate(
        [[mu], *(svec(p) for p in P), *(g.T.ravel() for g in G), *(y.T.ravel() for y in Y), *([svec(P[j])] * pairs)]
    )
    assert x.size == A.shape[1] and cost @ x == mu
    slack = b - A @ x
    lmis = theorem1_lmis(TA, C, F, P, G, Y, mu)
    assert len(lmis) == l * l + l * l * (l - 1) // 2
    size = 2 * nx + nw
    big = slack[: pairs * size * (size + 1) // 2].reshape(pairs, -1)
    for r in range(pairs):
        np.testing.assert_allclose(big[r], svec(lmis[r * l + j] - MARGIN * np.eye(size)), atol=1e-12)
    small = slack[pairs * size * (size + 1) // 2 :].reshape(pairs, l, -1)
    for k in range(l):
        np.testing.assert_allclose(small[:, k], np.broadcast_to(svec(P[j] - P[k]), small[:, k].shape), atol=1e-12)


@pytest.mark.slow
def test_direct_and_cvxpy_backends_agree():
    """Same μ* (the reduction is exact), and both solutions pass every LMI (19)–(20)."""
    low, high = np.full(3, 0.5), np.ones(3)
    direct = lpv_uio_design(SMALL, low, high)
    reference = lpv_uio_design(SMALL, low, high, backend="cvxpy")
    assert direct.mu == pytest.approx(reference.mu, rel=1e-5)
    for design in (direct, reference):
        assert design.min_eigenvalue > 0.9 * MARGIN
        assert max_spectral_radius(SMALL, design.gain, low, high) < 1


def test_the_direct_design_is_deterministic():
    low, high = np.full(3, 0.5), np.ones(3)
    first, second = (lpv_uio_design(SMALL, low, high) for _ in range(2))
    assert first.mu == second.mu
    np.testing.assert_array_equal(first.G, second.G)
    np.testing.assert_array_equal(first.Y, second.Y)


@pytest.mark.slow
def test_three_tank_design_reaches_the_reference_sigma():
    """Γ = [0.5, 1]^4, 16 vertices: 136 LMIs of size 13 and 2176 of size 4 in place of the 2176 of
    size 13; σ = 1.53030 is what the cvxpy route (the LMIs as printed) gives (docs/three-tank.md)."""
    low, high = np.full(4, 0.5), np.ones(4)
    sizes = theorem1_conic_data(*vertex_matrices(THREE_TANK, low, high))[3]
    assert (sizes.count(13), sizes.count(4), len(sizes)) == (136, 2176, 2312)
    design = lpv_uio_design(THREE_TANK, low, high)
    assert design.sigma == pytest.approx(1.5302982, rel=1e-4)
    assert design.min_eigenvalue > 0.9 * MARGIN
    assert max_spectral_radius(THREE_TANK, design.gain, low, high) < 0.25


@pytest.mark.slow
def test_theorem_1_is_infeasible_on_the_papers_full_box():
    """Recorded in docs/three-tank.md: on Γ = [0.01, 1]^4 the LMIs (19)–(20) have no solution."""
    with pytest.raises(DesignError, match="infeasible"):
        lpv_uio_design(THREE_TANK, np.full(4, 0.01), np.ones(4))


def test_backend_errors_name_the_choices():
    with pytest.raises(ValueError, match="use 'direct'"):
        lpv_uio_design(SMALL, np.full(3, 0.5), np.ones(3), backend="mosek")
    with pytest.raises(ValueError, match="backend='cvxpy'"):
        lpv_uio_design(SMALL, np.full(3, 0.5), np.ones(3), solver="SCS", backend="direct")
