"""COFD unknown input observers of Cristofaro & Johansen, Sec. 3, on the ship of Sec. 4: the design
conditions of Theorem 3.1, residual decoupling, the fault-free bound under |b| ≤ ε, and isolation
of single faults and of common-mode pairs with cluster residuals, simulated on the linear model
(23) in closed loop with the paper's controller."""

from __future__ import annotations

import numpy as np
import pytest

import estimators
from estimators import LinearModel, ParameterError
from estimators.allocation import (
    VesselController,
    VesselControllerParams,
    cluster_matrix,
    cluster_ratios,
    pseudo_inverse_allocation,
)
from estimators.cofd import COFDDiagnosis
from estimators.cofd_design import (
    SHIP_CLUSTER_FAMILY,
    SHIP_F,
    SHIP_FAMILY,
    SHIP_PAIRS,
    DesignError,
    cluster_directions,
    cofd_family,
    cofd_observer,
    fault_signatures,
    output_directions,
    residual_bounds,
    uniform_subrank,
)
from estimators.isolation import unisolable
from tests.linear_vessel import X0, A, C, D, E, G, M, W, disturbance, exponential_faults, model, simulate

TAU = 0.1
F = np.diag(SHIP_F)
GROUPS = [(0, 1), (2, 3), (4, 5), (6,), (7,)]
FAMILY = [tuple(j - 1 for j in J) for J in SHIP_FAMILY]
CLUSTER_FAMILY = [tuple(j - 1 for j in J) for J in SHIP_CLUSTER_FAMILY]
EPSILON = 100.0  # small enough for every single fault to be isolable, see docs/vessel-fdi.md
ZETA = tuple(cluster_ratios(pseudo_inverse_allocation(G, D @ X0[3:]), GROUPS))  # ζ^(i) = u_2i(0)/u_2i−1(0), Sec. 4


def diagnosis(**params) -> COFDDiagnosis:
    return estimators.create("cofd", model(), {"disturbance_bound": EPSILON, **params}, TAU)


def residuals(trajectory) -> np.ndarray:
    """|r<h>_<i>| / thr<h>_<i> over time, shape (4, 3, ticks)."""
    return np.array(
        [
            [np.abs(trajectory.series(f"r{h}_{i}")) / trajectory.series(f"thr{h}_{i}") for i in (1, 2, 3)]
            for h in (1, 2, 3, 4)
        ]
    )


def first_time(trajectory, name: str) -> float | None:
    hits = np.flatnonzero(trajectory.series(name) > 0)
    return float(trajectory.t[hits[0]]) if hits.size else None


# -- design: Theorem 3.1 -----------------------------------------------------------------------------


def test_the_ships_W_has_uniform_sub_rank_1_yet_every_multi_index_of_the_paper_has_full_rank():
    """W2 = W4 (T1 and T2 sit at the same x, so their sway forces have the same yaw arm), so by
    eq. (12) k0 = 1; the paper's observers use ℓ = 3 columns each, which Theorem 3.1's condition 1,
    rank(W_J) = rank(C W_J) = ℓ, allows for exactly the multi-indices it picks (docs/errata.md)."""
    np.testing.assert_allclose(W[:, 1], W[:, 3], rtol=1e-12)
    assert uniform_subrank(W) == 1
    assert np.linalg.matrix_rank(W) == 3
    for J in FAMILY:
        assert np.linalg.matrix_rank(W[:, list(J)]) == np.linalg.matrix_rank(C @ W[:, list(J)]) == 3
    assert uniform_subrank(np.array([[1.0, 0.0, 1.0, 2.0], [0.0, 1.0, 1.0, -1.0]])) == 2
    assert uniform_subrank(np.array([[1.0, 2.0, 0.0], [0.0, 0.0, 1.0]])) == 1


@pytest.mark.parametrize("family, columns", [(FAMILY, "W"), (CLUSTER_FAMILY, "W*")])
def test_each_observer_maps_its_columns_to_e1_e2_e3_and_meets_conditions_6_to_8(family, columns):
    """R^(h)[W_J] = [e1 e2 e3] (Sec. 4 and eq. (26)); F^(h) = F Hurwitz with S_j eigenvectors (14);
    and the coefficient of x in ė vanishes: (I − HC)A − KC + FHC = F (Sec. 3.1)."""
    target = cluster_directions(W, GROUPS, ZETA) if columns == "W*" else W
    for o in cofd_family(A, target, C, family, F):
        np.testing.assert_allclose(o.R @ target[:, list(o.J)], np.eye(6)[:, :3], atol=1e-9)
        np.testing.assert_allclose(o.R, np.eye(6) - o.H @ C, atol=1e-12)  # eq. (6)
        np.testing.assert_allclose(o.R @ A - o.K1 @ C, F, atol=1e-9)  # eq. (7)
        np.testing.assert_allclose(o.K2, F @ o.H, atol=1e-12)  # eq. (8)
        np.testing.assert_allclose(o.R @ A - o.K @ C + F @ o.H @ C, F, atol=1e-9)
        assert np.max(np.linalg.eigvals(o.F).real) < 0
        np.testing.assert_allclose(F @ o.S_hat, o.S_hat @ np.diag(SHIP_F[:3]), atol=1e-12)  # eq. (14)


def test_the_fault_signatures_are_the_ones_the_paper_reads_for_T1():
    """Sec. 4: with a fault on T1, r^(1) moves along e1 and e2 but not e3, and r^(2), r^(3), r^(4)
    move along e3 (W1 is their third column). Every thruster has a signature no other has."""
    signatures = fault_signatures(cofd_family(A, W, C, FAMILY, F), C, W, GROUPS)
    assert signatures[0, :, 0].tolist() == [True, True, False]
    assert signatures[1:, 2, 0].all()
    assert unisolable(signatures, [(j,) for j in range(5)]) == []
    assert len({signatures[:, :, j].tobytes() for j in range(5)}) == 5


def test_single_fault_observers_cannot_isolate_common_mode_pairs_but_cluster_residuals_can():
    """Sec. 3.3: a pair of thrusters moves so many components that it is confused with other faults
    (every Table 1 pair clashes with something); the cluster family (26) on W* isolates every
    single fault and every pair of Table 1."""
    hypotheses = [(j,) for j in range(5)] + [tuple(j - 1 for j in pair) for pair in SHIP_PAIRS]
    single = fault_signatures(cofd_family(A, W, C, FAMILY, F), C, W, GROUPS)
    clashing = {H for H, _ in unisolable(single, hypotheses)}
    assert all(tuple(j - 1 for j in pair) in clashing for pair in SHIP_PAIRS)
    W_star = cluster_directions(W, GROUPS, ZETA)
    cluster = fault_signatures(cofd_family(A, W_star, C, CLUSTER_FAMILY, F), C, W_star, [(j,) for j in range(5)])
    assert unisolable(cluster, hypotheses) == []


def test_cluster_direction_is_the_effect_of_the_constrained_inputs():
    """Under u_2i = ζ u_2i−1 (24), thruster i acts along W_{2i−1} + ζ W_{2i} (times u_2i−1); the
    printed (25), ζ W_{2i−1} + W_{2i}, is another direction (docs/errata.md)."""
    W_star = cluster_directions(W, GROUPS, ZETA)
    u = cluster_matrix(GROUPS, ZETA, 8) @ np.array([3.0, -2.0, 5.0, 7.0, 11.0])
    np.testing.assert_allclose(W @ u, W_star @ np.array([3.0, -2.0, 5.0, 7.0, 11.0]), rtol=1e-12)
    printed = ZETA[0] * W[:, 0] + W[:, 1]
    cosine = printed @ W_star[:, 0] / np.linalg.norm(printed) / np.linalg.norm(W_star[:, 0])
    assert cosine < 0.99


def test_the_residual_bound_has_the_closed_form_for_diagonal_F():
    """sup |r_i| = ε |row_i(R E)| / |f_i| under |b|₂ ≤ ε when C = I and F is diagonal."""
    for o in cofd_family(A, W, C, FAMILY, F):
        closed = 5e6 * np.linalg.norm(o.R @ E, axis=1) / np.abs(SHIP_F)
        np.testing.assert_allclose(residual_bounds(o, C, E, 5e6), closed, rtol=1e-8, atol=1e-6)
        assert np.all(closed[3:] < 1e-6 * closed[:3].max())  # R E lives in span{e1, e2, e3}


# -- design errors ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "params, field, words",
    [
        ({"family": [[2, 4, 1]]}, "family", "Theorem 3.1"),  # W2 = W4
        ({"family": [[1, 2, 9]]}, "family", "1…8"),
        ({"F": [-1, -1, 2, -5, -6, -7]}, "F", "negative"),
        ({"F": [-1, -1, -2]}, "F", "6 diagonal"),
        ({"zeta": [2.0, 3.0]}, "zeta", "need 3"),
        ({"margin": 0.5}, "margin", "at least 1"),
        ({"groups": [[1, 2], [3, 4], [5, 6], [7]]}, "groups", "split the inputs"),
        ({"pairs": [[2, 5]]}, "family", "cannot be isolated"),
        ({"family": [[1, 2, 3], [3, 4, 1], [5, 6, 1]]}, "family", "cannot be isolated"),  # T4, T5 unseparated
    ],
)
def test_bad_designs_name_the_parameter_and_the_fix(params, field, words):
    with pytest.raises(ParameterError) as error:
        diagnosis(**params)
    assert error.value.parameter == field
    assert words in str(error.value)


def test_design_functions_check_every_condition():
    with pytest.raises(DesignError, match="condition \\(14\\)"):
        cofd_observer(A, W, C, (0, 1, 2), F + np.eye(6, k=1) * 0.5)  # e2 no longer an eigenvector
    with pytest.raises(DesignError, match="rank\\(C\\)"):
        output_directions(np.array([[1.0, 0.0], [2.0, 0.0]]))
    with pytest.raises(DesignError, match="no solution K1"):
        A3, C3 = np.diag([-1.0, -2.0, -3.0]), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        cofd_observer(A3, np.array([[1.0], [0.0], [0.0]]), C3, (0,), np.diag([-1.0, -2.0, -5.0]))
    with pytest.raises(DesignError, match="eq. \\(21\\)"):
        cluster_directions(W, [(0, 2, 4), (1,), (3,), (5,), (6,), (7,)], [-1.0, 0.0])  # no surge force left
    no_disturbance = LinearModel(A, W, C, np.zeros((6, 8)), None, model().states, model().inputs, model().outputs)
    with pytest.raises(ParameterError, match="^E: "):
        estimators.create("cofd", no_disturbance, {}, TAU)


# -- fault-free: thresholds from ε -------------------------------------------------------------------


@pytest.mark.parametrize("h", [0, 1, 2, 3])
def test_the_worst_case_disturbance_reaches_the_bound_of_each_component_without_an_alarm(h):
    """The constant b of norm ε along row i of R^(h) E drives r^(h)_i to its bound (threshold /
    margin): the bound is attained, and the margin keeps the alarm off."""
    for i in range(3):
        estimator = diagnosis()
        row = (estimator.observers[h].R @ E)[i]
        worst = EPSILON * row / np.linalg.norm(row)
        trajectory = simulate(30.0, TAU, VesselController(M, D, G, TAU), estimator, b=lambda t, worst=worst: worst)
        ratio = residuals(trajectory)
        assert trajectory.series("alarm").max() == 0
        assert ratio[h, i, -1] == pytest.approx(1 / 1.2, rel=1e-3)
        assert ratio.max() <= (1 / 1.2) * (1 + 1e-4)  # sampling (y interpolated between ticks) adds 3e-5


def test_no_alarm_without_faults_under_the_papers_disturbance_bound():
    """ε = 5·10⁶ (Sec. 4), a current plus turning waves of that size, 300 s."""
    estimator = diagnosis(disturbance_bound=5e6)
    trajectory = simulate(300.0, TAU, VesselController(M, D, G, TAU), estimator, b=disturbance(5e6, seed=7))
    assert trajectory.series("alarm").max() == 0
    assert trajectory.series("fault_mask").max() == 0
    assert residuals(trajectory).max() < 1 / 1.2


# -- single faults ---------------------------------------------------------------------------------


def test_T1_fault_is_isolated_as_the_paper_reads_the_residuals():
    """δ1 = e^(−0.03 t) (Sec. 4, Figs. 2–3): r^(1) along e3 stays below its threshold while e1, e2
    exceed theirs; r^(2), r^(3), r^(4) exceed theirs along e3; T1 alone is reported."""
    trajectory = simulate(
        60.0,
        TAU,
        VesselController(M, D, G, TAU),
        diagnosis(),
        exponential_faults({1: 0.03}),
        disturbance(EPSILON, seed=1),
    )
    ratio = residuals(trajectory)
    assert ratio[0, 2].max() < 1
    assert ratio[0, 0].max() > 10 and ratio[0, 1].max() > 10
    assert all(ratio[h, 2].max() > 10 for h in (1, 2, 3))
    assert set(trajectory.series("fault_mask")) == {0.0, 1.0}
    assert trajectory.series("isolated_T1")[-1] == 1
    assert first_time(trajectory, "alarm") < first_time(trajectory, "fault_mask") <= 5.0


@pytest.mark.parametrize("thruster", [1, 2, 3, 4, 5])
def test_each_single_fault_is_isolated_to_its_thruster(thruster):
    trajectory = simulate(
        60.0,
        TAU,
        VesselController(M, D, G, TAU),
        diagnosis(),
        exponential_faults({thruster: 0.03}),
        disturbance(EPSILON, seed=thruster),
    )
    mask = trajectory.series("fault_mask")
    assert set(mask) <= {0.0, float(1 << (thruster - 1))}
    assert mask[-1] == 1 << (thruster - 1)
    signatures = diagnosis().signatures
    quiet = ~signatures[:, :, thruster - 1]
    assert residuals(trajectory)[quiet].max() < 1  # the structurally insensitive components stay below threshold


def test_isolation_waits_for_persistence():
    fast = simulate(
        20.0, TAU, VesselController(M, D, G, TAU), diagnosis(persistence=0.0), exponential_faults({1: 0.03})
    )
    slow = simulate(
        20.0, TAU, VesselController(M, D, G, TAU), diagnosis(persistence=3.0), exponential_faults({1: 0.03})
    )
    assert first_time(slow, "fault_mask") == pytest.approx(first_time(fast, "fault_mask") + 3.0)


# -- common-mode pairs: cluster residuals ----------------------------------------------------------


def cluster_run(faults: dict[int, float], duration: float = 120.0, seed: int = 2):
    controller = VesselController(M, D, G, TAU, VesselControllerParams(zeta=ZETA))
    return simulate(
        duration, TAU, controller, diagnosis(zeta=list(ZETA)), exponential_faults(faults), disturbance(EPSILON, seed)
    )


def test_T2_T5_common_mode_fault_is_isolated_by_cluster_residuals():
    """δ2 = e^(−0.02 t), δ5 = e^(−0.01 t) (Sec. 4, Fig. 4): the cluster residual r^(4) stays below
    threshold along e2 and exceeds it along e1 and e3; every other cluster residual exceeds its
    thresholds along e1, e2, e3; T2 and T5 are reported, nothing else."""
    trajectory = cluster_run({2: 0.02, 5: 0.01})
    ratio = residuals(trajectory)
    assert ratio[3, 1].max() < 1
    assert ratio[3, 0].max() > 10 and ratio[3, 2].max() > 10
    assert all(ratio[h, i].max() > 1 for h in (0, 1, 2) for i in range(3))
    mask = trajectory.series("fault_mask").astype(int)
    assert np.bitwise_or.reduce(mask) == mask[-1] == 2 + 16  # T2 may come first (δ5 decays slower), never another
    assert trajectory.series("constraints_met").min() == 1


@pytest.mark.parametrize("pair", [pair for pair in SHIP_PAIRS if pair != (2, 5)])
def test_the_other_common_mode_pairs_of_table_1_are_isolated(pair):
    trajectory = cluster_run({pair[0]: 0.03, pair[1]: 0.03}, duration=60.0)
    mask = sum(1 << (j - 1) for j in pair)
    assert set(trajectory.series("fault_mask")) <= {0.0, float(mask)}
    assert trajectory.series("fault_mask")[-1] == mask


def test_cluster_isolation_waits_while_the_commands_break_the_constraints():
    """Without the constraints (24) the fault directions are not those of W*: no isolation. (The
    paper's ratios 2.27, 3.41, 1.38 against the unconstrained pseudo-inverse allocation.)"""
    trajectory = simulate(
        60.0, TAU, VesselController(M, D, G, TAU), diagnosis(zeta=[2.27, 3.41, 1.38]), exponential_faults({2: 0.03})
    )
    assert trajectory.series("constraints_met")[1:].max() == 0
    assert trajectory.series("alarm").max() == 1
    assert trajectory.series("fault_mask").max() == 0


def test_the_estimator_is_registered_with_its_diagnostics():
    channels = [d.name for d in estimators.ESTIMATORS["cofd"].diagnostic_channels(model().states, model().outputs)]
    assert channels[:3] == ["r1_1", "r1_2", "r1_3"] and "thr4_3" in channels
    assert {"alarm", "fault_mask", "constraints_met", *(f"isolated_T{j}" for j in range(1, 6))} <= set(channels)
    estimate = diagnosis().step(X0, np.zeros(8))
    assert set(estimate.diagnostics) == set(channels)
    np.testing.assert_allclose(estimate.x, X0)  # x̂(0) = C⁺ y(0)
