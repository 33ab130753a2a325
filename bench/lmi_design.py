"""Time of the LMI designs of IJC 2018 (Behzad et al.) on the paper's three-tank model (59), and
the H∞ bound σ each achieves.

- LTI (baseline, measured in the same run): the UIO's H∞ gain for the healthy sensors only, i.e.
  Theorem 1 on the single vertex γ = 1: the "standard linear time-invariant case" that Sec. 1
  says the LFT design is comparable to;
- LFT: Theorem 2, LMI (42), one constant gain for all γ̂ in Γ (scalar multiplier, as printed, and
  the diagonal multipliers);
- LPV: Theorem 1, LMIs (19)–(20) on the 2^4 = 16 vertices of Γ (256 + 1920 LMIs of size 13),
  solved as the equivalent 136 LMIs of size 13 and 2176 of size 4 assembled directly for Clarabel
  (``backend="direct"``); with ``--reference`` also through cvxpy with the LMIs as printed
  (``backend="cvxpy"``, about 100 s), and the relative difference of the two σ.

Γ = [γ̲, 1]^4 with γ̲ = ``--gamma-min`` (default 0.5: both designs are infeasible on the paper's
[0.01, 1]^4, see docs/three-tank.md). The paper reports ≈ 9 h (LPV) and ≈ 6 min (LFT) with
YALMIP/SeDuMi; the targets here are 60 s and 2 s. Each figure is one whole design (building the
problem, solving it, checking every LMI), after a warm-up design that loads the solver; the LTI
baseline is the direct LPV design on one vertex.

Usage: python bench/lmi_design.py [--json] [--gamma-min G] [--skip-lpv] [--reference]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.common import bench_parser, print_figures  # noqa: E402
from estimators.lft_design import lft_uio_design  # noqa: E402
from estimators.lmi import SensorFaultModel, max_spectral_radius  # noqa: E402
from estimators.lpv_design import lpv_uio_design  # noqa: E402
from mjcf.three_tank import PAPER_A, PAPER_B, PAPER_C, PAPER_E

PAPER_SECONDS = {"lpv": 9 * 3600.0, "lft": 6 * 60.0}
TARGET_SECONDS = {"lpv": 60.0, "lft": 2.0}


def timed(design):
    start = time.perf_counter()
    result = design()
    return result, time.perf_counter() - start


def lti_and_lft(model: SensorFaultModel, low: np.ndarray, high: np.ndarray) -> dict[str, float]:
    """The LTI baseline and the LFT designs (Theorem 2, scalar and diagonal multipliers): time and σ."""
    lft_uio_design(model, low, high)  # warm-up: imports and solver start-up
    lti, lti_s = timed(lambda: lpv_uio_design(model, high, high, vertices=high[None, :]))
    lft, lft_s = timed(lambda: lft_uio_design(model, low, high))
    lft_diag, lft_diag_s = timed(lambda: lft_uio_design(model, low, high, multiplier="diagonal"))
    return {
        "lti_design_s": lti_s,
        "lti_sigma": lti.sigma,
        "lft_design_s": lft_s,
        "lft_sigma": lft.sigma,
        "lft_rho": max_spectral_radius(model, lambda g: lft.L, low, high, form="lft"),
        "lft_diagonal_design_s": lft_diag_s,
        "lft_diagonal_sigma": lft_diag.sigma,
        "lft_ratio": lft_s / lti_s,
        "lft_speedup_vs_paper": PAPER_SECONDS["lft"] / lft_s,
    }


def lpv(model: SensorFaultModel, low: np.ndarray, high: np.ndarray, lti_s: float, reference: bool) -> dict[str, float]:
    """The LPV design (Theorem 1, direct to Clarabel), and with ``reference`` the same through cvxpy."""
    design, lpv_s = timed(lambda: lpv_uio_design(model, low, high))
    figures = {
        "lpv_design_s": lpv_s,
        "lpv_sigma": design.sigma,
        "lpv_rho": max_spectral_radius(model, design.gain, low, high),
        "lpv_min_eigenvalue": design.min_eigenvalue,
        "lpv_ratio": lpv_s / lti_s,
        "lpv_speedup_vs_paper": PAPER_SECONDS["lpv"] / lpv_s,
    }
    if reference:
        ref, ref_s = timed(lambda: lpv_uio_design(model, low, high, backend="cvxpy"))
        figures |= {
            "lpv_cvxpy_design_s": ref_s,
            "lpv_cvxpy_sigma": ref.sigma,
            "lpv_cvxpy_ratio": ref_s / lti_s,
            "lpv_sigma_rel_diff": abs(design.sigma - ref.sigma) / ref.sigma,
        }
    return figures


def print_table(figures: dict[str, float]) -> None:
    """Each design's time, its ratio to the LTI baseline's, σ, the target and the paper's time."""
    print(f"LMI designs on the three-tank model (59), Γ = [{figures['gamma_min']:g}, 1]^4\n")
    print(f"{'design':<28}{'time (s)':>10}{'× LTI':>9}{'σ':>10}{'target (s)':>12}{'paper (s)':>11}")
    rows = [
        ("LTI (γ = 1, baseline)", "lti", None, None),
        ("LFT, Theorem 2", "lft", TARGET_SECONDS["lft"], PAPER_SECONDS["lft"]),
        ("LFT, diagonal multipliers", "lft_diagonal", TARGET_SECONDS["lft"], PAPER_SECONDS["lft"]),
        ("LPV, Theorem 1", "lpv", TARGET_SECONDS["lpv"], PAPER_SECONDS["lpv"]),
        ("LPV, as printed, via cvxpy", "lpv_cvxpy", None, None),
    ]
    for name, key, target, paper in rows:
        if f"{key}_design_s" not in figures:
            continue
        seconds, sigma = figures[f"{key}_design_s"], figures[f"{key}_sigma"]
        print(
            f"{name:<28}{seconds:>10.2f}{seconds / figures['lti_design_s']:>9.1f}{sigma:>10.3f}"
            f"{'' if target is None else f'{target:>12g}'}{'' if paper is None else f'{paper:>11g}'}"
        )
    if "lpv_sigma_rel_diff" in figures:
        print(f"\nLPV σ, direct against cvxpy: relative difference {figures['lpv_sigma_rel_diff']:.1e}")


def main(argv: list[str] | None = None) -> int:
    parser = bench_parser(__doc__)
    parser.add_argument("--gamma-min", type=float, default=0.5, help="lower corner of Γ (default 0.5)")
    parser.add_argument("--skip-lpv", action="store_true", help="leave out the LPV design")
    parser.add_argument("--reference", action="store_true", help="also the LPV design through cvxpy (about 100 s)")
    args = parser.parse_args(argv)
    model = SensorFaultModel(PAPER_A, PAPER_B, PAPER_E, PAPER_C, np.ones((4, 1)))
    low, high = np.full(4, args.gamma_min), np.ones(4)
    figures = {"gamma_min": args.gamma_min} | lti_and_lft(model, low, high)
    if not args.skip_lpv:
        figures |= lpv(model, low, high, figures["lti_design_s"], args.reference)
    print_figures(figures, args.json, print_table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
