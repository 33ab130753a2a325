"""Figures of docs/vessel-fdi.md: COFD thresholds per unit ε, the largest ε at which each fault is
still isolable (full loss, nominal allocation), the cluster ratios ζ of our allocation, and
detection/isolation times on the linear model (23) in closed loop (tests/linear_vessel.py).

    .venv/bin/python bench/vessel_fdi.py [--epsilon 100] [--json]

Not a speed benchmark: the design figures the scenarios' choices rest on. ``--json`` prints them
as one JSON object (``zeta``, ``largest_epsilon``, ``closed_loop``).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' linear ship model

from estimators import create
from estimators.allocation import VesselController, VesselControllerParams, cluster_ratios, pseudo_inverse_allocation
from estimators.cofd_design import SHIP_PAIRS
from estimators.isolation import isolate
from tests.linear_vessel import X0, D, G, M, W, disturbance, exponential_faults, model, simulate

GROUPS = [(0, 1), (2, 3), (4, 5), (6,), (7,)]


def largest_epsilon(estimator, u: np.ndarray, faulty: tuple[int, ...]) -> float:
    """The largest ε at which the steady residual of a full loss of ``faulty`` (inputs u held)
    still isolates it: component i fires while ε < |e_∞,i| / (threshold_i / ε)."""
    per_epsilon = estimator.thresholds / estimator.params.disturbance_bound
    columns = W @ estimator.N if estimator.params.zeta is not None else W
    v = np.linalg.lstsq(estimator.N, u, rcond=None)[0] if estimator.params.zeta is not None else u
    groups = [(j,) for j in range(5)] if estimator.params.zeta is not None else GROUPS
    steady = sum(
        np.array(
            [
                np.linalg.solve(o.F, o.R @ columns[:, list(groups[j])] @ v[list(groups[j])])[:3]
                for o in estimator.observers
            ]
        )
        for j in faulty
    )
    ratio = np.abs(steady) / per_epsilon
    for epsilon in sorted(set(ratio.ravel()), reverse=True):
        if isolate(ratio > epsilon * (1 - 1e-9), estimator.signatures, estimator.hypotheses) == faulty:
            return epsilon * (1 - 1e-9)
    return 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epsilon", type=float, default=100.0, help="disturbance bound of the simulated runs (N)")
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object of the figures instead of the tables"
    )
    args = parser.parse_args()
    figures: dict = {"epsilon": args.epsilon, "largest_epsilon": {}, "closed_loop": {}}
    with contextlib.redirect_stdout(io.StringIO()) if args.json else contextlib.nullcontext():
        report(args.epsilon, figures)
    if args.json:
        print(json.dumps(figures))


def report(epsilon: float, figures: dict) -> None:
    """Print the tables, and collect their figures."""
    tau = 0.1
    u0 = pseudo_inverse_allocation(G, D @ X0[3:])
    zeta = tuple(cluster_ratios(u0, GROUPS))
    figures["zeta"] = [round(z, 4) for z in zeta]
    print("u(0) = G⁺ D ν0 =", np.round(u0, 1).tolist())
    print("ζ = u_2i(0)/u_2i−1(0) =", np.round(zeta, 3).tolist(), "(paper: 2.27, 3.41, 1.38)")
    single = create("cofd", model(), {"disturbance_bound": 1.0}, tau)
    cluster = create("cofd", model(), {"disturbance_bound": 1.0, "zeta": list(zeta)}, tau)
    for name, estimator in (("single-fault family", single), ("cluster family (26)", cluster)):
        print(f"\n{name}: thresholds / ε (margin {estimator.params.margin}), rows h, columns e1 e2 e3")
        print(np.round(estimator.thresholds, 3))
    print("\nlargest ε at which a full loss is isolated (nominal inputs):")
    for j in range(5):
        figures["largest_epsilon"][f"T{j + 1}"] = largest_epsilon(single, u0, (j,))
        print(
            f"  T{j + 1}: single family {largest_epsilon(single, u0, (j,)):9.0f} N   cluster family "
            f"{largest_epsilon(cluster, u0, (j,)):9.0f} N"
        )
    for pair in SHIP_PAIRS:
        H = tuple(j - 1 for j in pair)
        figures["largest_epsilon"][f"T{pair[0]}+T{pair[1]}"] = largest_epsilon(cluster, u0, H)
        print(f"  T{pair[0]}+T{pair[1]}: cluster family {largest_epsilon(cluster, u0, H):9.0f} N")
    closed_loop_table(epsilon, tau, zeta, figures)


def closed_loop_table(epsilon: float, tau: float, zeta: tuple[float, ...], figures: dict) -> None:
    """The closed loop on (23) for 120 s, nominal and with each fault and pair: when the fault is
    detected and isolated, and whether the isolation is right."""
    print(f"\nclosed loop on (23), ε = {epsilon:g} N, τ = {tau} s, 120 s, δ = e^(−rate t) from t = 0")
    print("| scenario | family | detected at (s) | first isolation (s) | complete at (s) | isolated | correct |")
    print("|---|---|---|---|---|---|---|")
    runs = [
        ("nominal", {}, False),
        *((f"T{j}", {j: 0.03}, False) for j in range(1, 6)),
        ("T2+T5 (δ2 = e^(−0.02t), δ5 = e^(−0.01t))", {2: 0.02, 5: 0.01}, True),
        *((f"T{a}+T{b}", {a: 0.03, b: 0.03}, True) for a, b in SHIP_PAIRS if (a, b) != (2, 5)),
    ]
    for label, faults, clustered in runs:
        figures["closed_loop"][label] = closed_loop_row(label, faults, clustered, epsilon, tau, zeta)


def closed_loop_row(label: str, faults: dict, clustered: bool, epsilon: float, tau: float, zeta: tuple) -> dict:
    """One closed-loop run, printed as a row of the table; its figures."""
    params = {"disturbance_bound": epsilon, **({"zeta": list(zeta)} if clustered else {})}
    controller = VesselController(M, D, G, tau, VesselControllerParams(zeta=zeta if clustered else None))
    trajectory = simulate(
        120.0,
        tau,
        controller,
        create("cofd", model(), params, tau),
        exponential_faults(faults),
        disturbance(epsilon, seed=1),
    )
    alarm, mask = trajectory.series("alarm"), trajectory.series("fault_mask")
    detected = trajectory.t[np.flatnonzero(alarm)[0]] if alarm.any() else None
    isolated = trajectory.t[np.flatnonzero(mask)[0]] if mask.any() else None
    found = [j + 1 for j in range(5) if int(mask[-1]) >> j & 1]
    complete = trajectory.t[np.flatnonzero(mask == mask[-1])[0]] if mask.any() else None
    ever = int(np.bitwise_or.reduce(mask.astype(int)))
    correct = found == sorted(faults) and ever == int(mask[-1])  # never a healthy thruster, all faulty ones in the end
    print(
        f"| {label} | {'cluster' if clustered else 'single'} | {'—' if detected is None else f'{detected:.1f}'} | "
        f"{'—' if isolated is None else f'{isolated:.1f}'} | {'—' if complete is None else f'{complete:.1f}'} | "
        f"{', '.join(f'T{j}' for j in found) or 'none'} | {'yes' if correct else 'NO'} |"
    )
    return {
        "detected_s": None if detected is None else float(detected),
        "isolated_s": None if complete is None else float(complete),
        "isolated": [f"T{j}" for j in found],
        "correct": bool(correct),
    }


if __name__ == "__main__":
    main()
