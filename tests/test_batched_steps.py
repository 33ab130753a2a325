"""The batched steps of the adaptive observer (TAC 2024) and of the COFD diagnosis against their single
steps, bit for bit, on inputs that take every branch of the logic each run has of its own: the
optimizer's zero cost, its ±eᵢ candidates and ties, the selector's determinant test at ε, the dead
zone, Algorithm 1, missing readings in some runs, and for COFD the constraint test (24), isolation
and its persistence, each firing in some runs and not in others."""

from __future__ import annotations

import numpy as np
import pytest

import estimators
from estimators.adaptive_law import (
    optimizer_step,
    optimizer_steps,
    scale_and_filter,
    scale_and_filter_runs,
    select,
    select_runs,
)
from estimators.allocation import VesselController, VesselControllerParams
from estimators.batched import check_batched, lstsq_runs, norms
from estimators.design import assumption2_factorization
from estimators.isolation import Isolation, hypothesis_signature
from tests.linear_masses import masses_model
from tests.linear_vessel import D, G, M, disturbance, exponential_faults, simulate
from tests.test_cofd import TAU, ZETA, diagnosis

P3 = ("x1", "x2", "x1_minus_x2")


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal in every bit (−0.0 is not 0.0), NaN equal to NaN."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and bool(np.all((a.view(np.int64) == b.view(np.int64)) | (np.isnan(a) & np.isnan(b))))


def test_the_norms_of_k_rows_are_numpys_norm_of_each_row():
    """By the dot kernel of ``np.linalg.norm``: a sum of squares rounds otherwise from 8 entries on."""
    rng = np.random.default_rng(4)
    for n in (1, 2, 3, 6, 8, 13, 40):
        v = rng.standard_normal((500, n)) * np.exp(rng.uniform(-5, 5, (500, n)))
        assert same_bits(norms(v), [np.linalg.norm(row) for row in v]), n


def test_least_squares_of_k_runs_are_numpys_lstsq_of_each():
    """Each system by its own gelsd, as ``np.linalg.lstsq`` solves it: tall, square, wide and rank
    deficient matrices, right-hand sides from tiny to huge; one gelsd of K right-hand sides rounds
    otherwise (checked here too, so that the test shows the difference it guards against)."""
    rng = np.random.default_rng(53)
    differs = 0
    for m, n in ((4, 3), (3, 3), (2, 3), (6, 2), (5, 5), (8, 4)):
        for deficient in (False, True):
            A = rng.standard_normal((m, n))
            if deficient:
                A[:, -1] = A[:, 0] * 0.5  # rank below min(m, n)
            b = rng.standard_normal((300, m)) * np.exp(rng.uniform(-8, 8, (300, 1)))
            alone = [np.linalg.lstsq(A, row, rcond=None)[0] for row in b]
            assert same_bits(lstsq_runs(A, b), alone), (m, n, deficient)
            differs += not same_bits(np.linalg.lstsq(A, b.T, rcond=None)[0].T, alone)
    assert differs > 0


# -- the adaptation law: K runs against one ---------------------------------------------------------


def adversarial_rows(rng: np.random.Generator, p: int, runs: int) -> tuple[np.ndarray, np.ndarray]:
    """z (unit rows) and φ of ``runs`` optimizer steps, every few rows one of the cases that take a
    branch: φ = 0, φ with a zero component (the candidate ±eᵢ, cost 0) with z's component of either
    sign, two zero components (a tie: the lowest i), z = eⱼ, uniform z and φ, extreme scales."""
    z = rng.normal(size=(runs, p))
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    phi = rng.normal(size=(runs, p)) * 10.0 ** rng.uniform(-8, 8, (runs, 1))
    phi[0::8] = 0.0
    phi[1::8, 1] = 0.0
    z[1::16, 1] = -np.abs(z[1::16, 1])
    phi[2::8, :2] = 0.0
    z[3::8] = np.eye(p)[p - 1]
    z[4::8], phi[4::8] = 1 / np.sqrt(p), 1.0
    phi[5::8] *= 10.0 ** rng.choice([-150, 150], size=(len(phi[5::8]), 1))
    return z, phi


def test_the_optimizer_of_k_runs_is_the_one_run_optimizer_bit_for_bit_on_every_branch():
    rng = np.random.default_rng(5)
    corners = negative = settled = 0
    for _ in range(120):
        p = int(rng.integers(2, 7))
        q = int(rng.integers(1, p + 1))
        Y = np.linalg.qr(rng.normal(size=(p, q)))[0]
        z, phi = adversarial_rows(rng, p, 40)
        with np.errstate(all="ignore"):  # the extreme scales overflow, alone as together
            alone = np.array([optimizer_step(z[k], phi[k], Y) for k in range(len(z))])
            together = optimizer_steps(z, phi, Y)
        assert same_bits(together, alone), (p, q)
        jumped = ~(np.abs(z) == 1.0).any(axis=1)  # the candidate ±eᵢ taken from elsewhere
        corners += int(((alone == 1.0).any(axis=1) & jumped).sum())
        negative += int(((alone == -1.0).any(axis=1) & jumped).sum())
        settled += int(np.all(alone == z, axis=1).sum())
    assert corners > 100 and negative > 50 and settled > 100  # the branches were taken
    Y, _, _ = assumption2_factorization(masses_model(P3).C)
    z = np.array([0.6, -0.48, 0.64])  # φ moves no reading but the third: e₁ and e₂ both cost 0
    tie = optimizer_steps(np.array([z]), np.array([[0.0, 0.0, 1.0]]), Y)[0]
    assert same_bits(tie, [1.0, 0.0, 0.0]) and same_bits(tie, optimizer_step(z, np.array([0.0, 0.0, 1.0]), Y))
    assert same_bits(optimizer_steps(-np.array([z]), np.array([[0.0, 0.0, 1.0]]), Y)[0], [-1.0, 0.0, 0.0])


def test_from_z_on_an_axis_the_optimizer_never_steps_into_a_nan():
    """z = ±eⱼ (where the candidate ±eᵢ leads): the search along eⱼ keeps z, whose β₀, β₁, β₂ are
    rounding noise (their quotient was once any ζ, ≈ −1 in 8 % of these rows: z + ζ eⱼ ≈ 0, a NaN z
    from then on); the step is a unit vector whose cost is at most z's, alone and together."""
    rng = np.random.default_rng(8)
    Y = rng.normal(size=(4, 2))
    phi = rng.normal(size=(4000, 4))
    z = np.eye(4)[rng.integers(0, 4, 4000)] * rng.choice([-1.0, 1.0], (4000, 1))
    alone = np.array([optimizer_step(z[k], phi[k], Y) for k in range(len(z))])
    assert same_bits(optimizer_steps(z, phi, Y), alone)
    np.testing.assert_allclose(norms(alone), 1.0, rtol=1e-15)
    cost = lambda z, phi: np.sum(((Y.T * phi) @ z) ** 2)  # noqa: E731
    assert all(cost(alone[k], phi[k]) <= cost(z[k], phi[k]) * (1 + 1e-12) for k in range(len(z)))


def test_the_selector_and_algorithm_1_of_k_runs_are_the_one_run_ones_at_their_thresholds():
    Y, _, _ = assumption2_factorization(masses_model(P3).C)
    rng = np.random.default_rng(6)
    z = rng.normal(size=(64, 3))
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    s = np.tile(np.ones(3) / np.sqrt(3), (64, 1))
    epsilon = float(np.abs(np.linalg.det((Y.T * z[0]) @ Y)))  # run 0 on the boundary |det R(z)| = ε
    s_next, h_next = select_runs(s, z, Y, epsilon)
    for k in range(len(z)):
        s_alone, h_alone = select(s[k], z[k], Y, epsilon)
        assert same_bits(s_next[k], s_alone) and h_next[k] == h_alone
    assert h_next[0] == 1 and 0 < h_next.sum() < len(z)  # held on the boundary, both answers elsewhere
    phi = rng.normal(size=(64, 3)) * 10.0 ** rng.uniform(-5, 1, (64, 1))
    filtered = rng.normal(size=(64, 3))
    eps_phi = float(np.median(norms(phi)))
    phi[1] *= eps_phi / np.linalg.norm(phi[1])  # |φ̂| = ε_φ, or within a rounding of it
    together = scale_and_filter_runs(phi, filtered, 0.05, eps_phi)
    for k in range(len(phi)):
        assert same_bits(together[k], scale_and_filter(phi[k], filtered[k], 0.05, eps_phi))


# -- the adaptive observer's batched step ------------------------------------------------------------


def masses_runs(biases: list[np.ndarray], ticks: int, noise: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """Readings (ticks, runs, p) and inputs (ticks, runs, 1) of the coupled masses from rest, each run
    with its own constant bias and noise, a few readings missing in some runs; run 0 stays at rest
    without noise (φ̂ = 0 exactly: the optimizer's zero cost)."""
    model = masses_model(P3)
    rng = np.random.default_rng(7)
    runs = len(biases)
    x = np.zeros((runs, model.n))
    y, u = np.empty((ticks, runs, model.p)), np.empty((ticks, runs, model.m))
    for k in range(ticks):
        u[k] = np.sin(0.05 * k + np.arange(runs))[:, None]
        u[k, 0] = 0.0
        y[k] = x @ model.C.T + np.array(biases) + noise * rng.standard_normal((runs, model.p))
        x = x @ model.A.T + u[k] @ model.B.T
    y[:, 0] = 0.0
    y[40:50, 2, 1] = np.nan  # run 2 loses a reading for a while
    y[60, 3] = np.nan  # run 3 loses every reading for a tick
    return y, u


def alone(make, y: np.ndarray, u: np.ndarray) -> dict[str, np.ndarray]:
    """Each run's diagnostics stepped alone, (ticks, runs) per name."""
    instances = [make() for _ in range(y.shape[1])]
    rows = [[e.step(y[k, r], u[k, r]).diagnostics for r, e in enumerate(instances)] for k in range(len(y))]
    return {name: np.array([[d[name] for d in row] for row in rows]) for name in rows[0][0]}


@pytest.mark.parametrize(
    "params",
    [
        {},
        {"filter": 0.05, "eps_phi": 0.5},  # Algorithm 1: |φ̂| below ε_φ in some runs, above in others
        {"dead_zone": 1.0},  # the optimizer held in runs 0 and 4, at some ticks in run 2 (noise), never in 1
        {"injection": True, "epsilon": 0.2},  # (52)–(53): z* has |det R| = 0.163 < ε, so h = 1 there
    ],
)
def test_the_adaptive_batched_step_equals_its_single_step_where_runs_take_other_branches(params):
    model = masses_model(P3)
    biases = [np.zeros(3), np.array([1.0, -1.5, 0.5]), np.array([0.02, 0.0, -0.01]), np.array([0.0, 3.0, -2.0])]
    biases += [np.zeros(3), np.array([-0.5, 0.2, 0.05])]
    y, u = masses_runs(biases, 150)
    y[:, 4], u[:, 4] = 1e-9, 0.0  # run 4: at rest, a tiny offset on every sensor

    def make():
        return estimators.create("adaptive", model, params)

    check_batched(make, y, u)
    seen = alone(make, y, u)
    z = np.stack([seen[f"z_{o}"] for o in P3], axis=2)
    moved = (z[1:] != z[:-1]).any(axis=2)  # (ticks − 1, runs)
    assert not moved[:, 0].any() and moved[:, 1].any()  # φ̂ = 0 holds z; a bias moves it
    if "dead_zone" in params:
        held = ~moved[:, 2]
        held[35:55] = False  # not the ticks around run 2's missing reading, which hold z anyway
        assert not moved[:, 4].any() and moved[:, 2].any() and held.any()
    if "injection" in params:  # the selector refuses z in run 1, never in run 0
        assert seen["h"][:, 0].max() == 0 and seen["h"][:, 1].max() == 1


# -- COFD: isolation, the constraint test, the batched step --------------------------------------------


def test_the_isolation_of_k_runs_is_the_definition_written_out():
    """Consistent: no fired component the hypothesis cannot move; the answer the unique minimal
    consistent hypothesis, else none (-1), on random fired patterns of the single and cluster families."""
    rng = np.random.default_rng(8)
    for estimator in (diagnosis(), diagnosis(zeta=list(ZETA))):
        signatures, hypotheses = estimator.signatures, estimator.hypotheses
        fired = rng.random((400, *signatures.shape[:2])) < rng.uniform(0.05, 0.6, (400, 1, 1))
        fired[:40] = [hypothesis_signature(signatures, hypotheses[k % len(hypotheses)]) for k in range(40)]
        fired[40] = False
        found = Isolation(signatures, hypotheses)(fired)
        for f, answer in zip(fired, found):
            consistent = [H for H in hypotheses if not (f & ~hypothesis_signature(signatures, H)).any()]
            minimal = [H for H in consistent if not any(set(o) < set(H) for o in consistent)]
            expected = hypotheses.index(minimal[0]) if f.any() and len(minimal) == 1 else -1
            assert answer == expected
        assert set(found[:40]) == set(range(len(hypotheses))) and found[40] == -1


def test_the_constraint_test_of_k_runs_is_each_runs_own_at_its_tolerance():
    estimator = diagnosis(zeta=list(ZETA))
    N, rng = estimator.N, np.random.default_rng(9)
    on = (N @ rng.normal(size=(N.shape[1], 200))).T * 100.0
    off = rng.normal(size=(200, N.shape[0]))
    off -= (N @ np.linalg.lstsq(N, off.T, rcond=None)[0]).T  # orthogonal to span N
    off /= np.abs(off).max(axis=1, keepdims=True)
    size = np.abs(on).max(axis=1, keepdims=True)
    scale = 1e-3 * size * (1.0 + rng.choice([-1.0, 1.0], (200, 1)) * 10.0 ** rng.uniform(-16, -3, (200, 1)))
    u = np.vstack([on + scale * off, on, off, np.full((1, N.shape[0]), np.nan)])  # near the tolerance, on, off
    together = estimator._constraints_met(u)
    each = np.array([estimator._constraints_met(row[None])[0] for row in u])
    assert np.array_equal(together, each)
    assert 0 < together[:200].sum() < 200 and together[200:400].all() and not together[400:].any()


def vessel_runs(*runs: tuple[dict[int, float], bool]) -> tuple[np.ndarray, np.ndarray]:
    """Readings and commands (ticks, runs, ·) of 8.5 s of the linear ship in closed loop, each run with
    its thruster faults and its controller (True: the cluster constraints (24) with ζ)."""
    ys, us = [], []
    for seed, (faults, clustered) in enumerate(runs):
        controller = VesselController(M, D, G, TAU, VesselControllerParams(zeta=ZETA if clustered else None))
        trajectory = simulate(8.5, TAU, controller, None, exponential_faults(faults), disturbance(100.0, seed))
        ys.append(trajectory.x)
        us.append(trajectory.u)
    return np.stack(ys, axis=1), np.stack(us, axis=1)


@pytest.mark.parametrize("cluster", [False, True])
def test_the_cofd_batched_step_equals_its_single_step_while_isolations_fire_and_latch_in_some_runs(cluster):
    """Runs without a fault, with a fast fault that latches and with a slow one that is still
    waiting out its persistence; with the cluster family also runs whose commands break (24)."""
    if cluster:
        y, u = vessel_runs(({}, True), ({2: 0.05, 5: 0.05}, True), ({3: 0.05, 4: 0.05}, True), ({2: 0.05}, False))
        u[40:, 2, 0] *= 1.01  # run 2's commands leave the constraints at 4 s
    else:
        y, u = vessel_runs(({}, False), ({1: 0.03}, False), ({3: 0.03}, False), ({4: 0.01}, False))
    y[20:30, 1, 2] = np.nan  # run 1 loses its heading for 1 s
    y[60, 0] = np.nan  # run 0 every reading for a tick

    def make():
        return diagnosis(persistence=2.0, zeta=list(ZETA) if cluster else None)

    check_batched(make, y, u)
    seen = alone(make, y, u)
    latched = seen["fault_mask"][-1]
    assert latched[0] == 0 and latched[1] > 0  # a fault latched in one run, none in another
    assert seen["alarm"][:, 0].max() == 0 and seen["alarm"][:, 1].max() == 1
    if cluster:
        met = seen["constraints_met"]
        assert met[:, 0].min() == 1 and met[:41, 2].min() == 1 and met[41:, 2].max() == 0
    else:
        assert latched[3] == 0 and seen["alarm"][:, 3].max() == 1  # T4's slow fault: alarmed, not yet latched
