"""Verdicts: what a comparison of two schemes on their common runs found, and what it could have found.

Two schemes of a leaderboard are compared on the runs both took part in. The runs of a campaign
share their random numbers across schemes (``cosim.campaign.spec``: every scheme of a run sees the
same noise, weather and faults), so a run is a *pair*: the run-to-run variation (the noise draw,
the fault's size, its target) cancels in the pair, and what remains is the schemes' difference.

Estimation errors (RMS after onset, ``e``): per run i the log ratio ``dᵢ = ln(e_next,i / e_i)``,
relative and unit-free (a 10 % larger error is ``ln 1.1`` whatever the case's unit), and

- **difference**: the two-sided Wilcoxon signed-rank test of ``d`` (``scipy.stats.wilcoxon``; exact
  for up to 50 pairs without ties, else the normal approximation). It assumes independent runs and
  a distribution of ``d`` symmetric about its median; it assumes no normality, so a run in which
  one scheme diverges does not swamp the others.
- **equivalence** within a declared margin δ (``ln(1 + δ)`` on the log scale): two one-sided
  signed-rank tests (TOST, Schuirmann 1987), of ``d + ln(1 + δ) > 0`` and ``d − ln(1 + δ) < 0``;
  its p is the larger of the two.

The difference is shown as a ratio ``exp(θ̂)`` with θ̂ the Hodges–Lehmann estimate of the shift of
``d`` (the median of the Walsh averages, the signed-rank test's own estimate: the test leans the
way θ̂ does) and its distribution-free 95 % interval.

Diagnoses (schemes with no estimation error of their own): per run, which of the two diagnosed
better (``scores.diagnosis_outcome``); the difference by the two-sided sign test (exact
binomial, ``scipy.stats.binomtest``) over the runs where they differ, and equivalence by the
one-sided binomial test that they differ on fewer than a share δ of the runs.

Every p of a board is adjusted by Holm's step-down procedure, the difference tests as one family
and the equivalence tests as another, each at α = 0.05. Each comparison's verdict is one of

- ``separated``: the adjusted difference p < α;
- ``tied``: not separated, and the adjusted equivalence p < α: shown equivalent within ±δ;
- ``not separated``: neither; the runs cannot tell.

What the runs could tell is stated with every verdict, at the level α' = α / m of the board's m
difference tests (Holm's first step: a comparison whose p is below it is separated whatever the
others' p), with power 1 − β = 0.8:

- the signed-rank test of n pairs cannot give a p below 2 · 2⁻ⁿ, so it needs
  ``n ≥ 1 + log₂(1/α')`` pairs to separate anything (9 pairs at α' = 0.0025);
- the **smallest detectable difference** δ_min: the relative difference ``exp(θ) − 1`` for which the
  test at α' has power 0.8, with σ the standard deviation of the observed ``d``: θ solves

      P(|T| > t_{1−α'/2, ν}) = 0.8,  T ~ noncentral t(ν = n_e − 1, λ = θ √n_e / σ),  n_e = 3n / π,

  the paired t-test's power with n scaled by the signed-rank test's asymptotic relative efficiency
  against it under normality (3/π; Lehmann, *Nonparametrics*, 1975);
- when two schemes are not separated, the **runs needed** to separate a difference of the size
  observed (θ̂, below): the smallest N with that power, and at least the floor above.

Both are planning figures (about N), not guarantees: σ comes from the runs at hand; where d has
heavier tails than a normal the signed-rank test is the more efficient and N is an overestimate.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

ALPHA = 0.05
"""The family-wise error rate of a board's difference tests (and of its equivalence tests)."""
POWER = 0.8
"""The power at which the detectable difference and the runs needed are stated."""
MARGIN = 0.05
"""The default equivalence margin: errors within ±5 % (a ratio within [1/1.05, 1.05]); the share of
runs on which two diagnoses may differ."""
EFFICIENCY = 3 / math.pi
"""Asymptotic relative efficiency of the signed-rank test against the t-test for normal differences."""
Z95 = 1.959963984540054
"""The standard normal's 97.5th percentile."""
MOST_RUNS = 10**7
"""Runs needed beyond this are reported as this many: no campaign separates such a difference."""

SEPARATED, TIED, NOT_SEPARATED = "separated", "tied", "not separated"


def holm(pvalues: Sequence[float]) -> list[float]:
    """Holm's step-down adjustment of m p-values (family-wise error rate), in their order."""
    m = len(pvalues)
    adjusted = [0.0] * m
    running = 0.0
    for step, index in enumerate(sorted(range(m), key=lambda i: pvalues[i])):
        running = max(running, min(1.0, (m - step) * pvalues[index]))
        adjusted[index] = running
    return adjusted


def fewest_pairs(level: float) -> int:
    """The fewest pairs with which a two-sided signed-rank (or sign) test can reach p ≤ ``level``:
    its smallest p with n pairs, all of one sign, is 2 · 2⁻ⁿ."""
    return max(1, math.ceil(1 + math.log2(1 / level) - 1e-12))


def _t_power(effect: float, n: float, level: float) -> float:
    """Power of the two-sided one-sample t-test at ``level`` with n pairs against the standardized
    effect θ/σ (noncentral t)."""
    from scipy.stats import nct, t

    df = n - 1
    critical = float(t.ppf(1 - level / 2, df))
    shift = effect * math.sqrt(n)
    upper, lower = float(nct.sf(critical, df, shift)), float(nct.cdf(-critical, df, shift))
    # far in its tails SciPy's noncentral t gives NaN where the probability is 0 or 1
    upper = (1.0 if shift > critical else 0.0) if math.isnan(upper) else upper
    return upper + (0.0 if math.isnan(lower) else lower)


def detectable(pairs: int, spread: float | None, level: float) -> float | None:
    """The smallest relative difference the signed-rank test of ``pairs`` pairs at ``level`` detects
    with power ``POWER``, for log ratios of standard deviation ``spread``; None where the pairs are
    too few to reach ``level`` at all (or too few to know their spread)."""
    if pairs < max(2, fewest_pairs(level)) or spread is None:
        return None
    if spread == 0:
        return 0.0
    from scipy.optimize import brentq

    n = pairs * EFFICIENCY
    effect = brentq(lambda e: _t_power(e, n, level) - POWER, 1e-9, 100.0)
    return math.expm1(effect * spread)


def runs_needed(shift: float | None, spread: float | None, level: float) -> int | None:
    """About how many pairs the signed-rank test at ``level`` needs to separate a log ratio of
    ``shift`` with power ``POWER``, for log ratios of standard deviation ``spread``; None where no
    difference was observed or its spread is unknown."""
    if shift is None or spread is None or shift == 0:
        return None
    floor = max(2, fewest_pairs(level))
    if spread == 0:
        return floor
    effect = abs(shift) / spread

    def enough(pairs: int) -> bool:
        return _t_power(effect, pairs * EFFICIENCY, level) >= POWER

    if enough(floor):
        return floor
    low, high = floor, floor * 2
    while not enough(high):
        if high >= MOST_RUNS:
            return MOST_RUNS
        low, high = high, high * 2
    while high - low > 1:  # enough(high), not enough(low)
        middle = (low + high) // 2
        low, high = (low, middle) if enough(middle) else (middle, high)
    return high


BOOTSTRAP = 2000


def bootstrap_median(values: list[float], seed: int = 0) -> tuple[float, float] | None:
    """95 % percentile-bootstrap interval of the median (2000 resamples, seeded; None under 5 values)."""
    if len(values) < 5:
        return None
    rng = np.random.default_rng(seed)
    data = np.asarray(values)
    medians = np.median(rng.choice(data, size=(BOOTSTRAP, data.size), replace=True), axis=1)
    return float(np.percentile(medians, 2.5)), float(np.percentile(medians, 97.5))


WALSH = 3000
"""Above this many pairs the Walsh averages are a seeded sample of 4.5 million, not all of them."""


def hodges_lehmann(values: Sequence[float], seed: int = 0) -> tuple[float, tuple[float, float] | None]:
    """The Hodges–Lehmann estimate of the centre of ``values`` (the median of the Walsh averages
    (dᵢ + dⱼ)/2, i ≤ j: the shift the signed-rank test tests), and its distribution-free 95 % interval
    (the Walsh averages of ranks K and M + 1 − K, M = n(n + 1)/2, K from the signed-rank statistic's
    normal approximation; None where n is too small for one)."""
    d = np.asarray(values, dtype=float)
    n = d.size
    if n > WALSH:
        rng = np.random.default_rng(seed)
        i, j = rng.integers(0, n, (2, WALSH * (WALSH + 1) // 2))
        walsh = np.sort((d[np.minimum(i, j)] + d[np.maximum(i, j)]) / 2)
    else:
        i, j = np.triu_indices(n)
        walsh = np.sort((d[i] + d[j]) / 2)
    m = walsh.size
    estimate = float(np.median(walsh))
    scale = m / (n * (n + 1) / 2)  # ranks of a sample of the Walsh averages scale with its size
    k = math.floor(scale * (n * (n + 1) / 4 - Z95 * math.sqrt(n * (n + 1) * (2 * n + 1) / 24)))
    if k < 1:
        return estimate, None
    return estimate, (float(walsh[k - 1]), float(walsh[m - k]))


def paired_comparison(first: dict[Any, float], second: dict[Any, float], margin: float = MARGIN) -> dict[str, Any]:
    """``second`` against ``first`` on the runs both have: how many, the median difference in their
    unit and its 95 % bootstrap interval, the ratio ``second/first`` (Hodges–Lehmann) and its interval, the
    signed-rank tests' p of a difference and of equivalence within ``margin``, and the spread and
    shift of the log ratios (for ``judge``). Holm's adjustment and the verdict come later, over the
    whole board."""
    from scipy.stats import wilcoxon

    runs = sorted(first.keys() & second.keys(), key=str)
    differences = [second[run] - first[run] for run in runs]
    logs = [math.log(second[r] / first[r]) for r in runs if first[r] > 0 and second[r] > 0]
    nonzero = [d for d in logs if d != 0.0]
    bound = math.log1p(margin)
    p = float(wilcoxon(nonzero).pvalue) if nonzero else 1.0
    if logs:
        above = float(wilcoxon([d + bound for d in logs], alternative="greater").pvalue)
        below = float(wilcoxon([d - bound for d in logs], alternative="less").pvalue)
        equivalence = max(above, below)
    else:
        equivalence = 1.0
    shift, interval = hodges_lehmann(logs) if logs else (None, None)
    return {
        "measure": "rms_post_fault",
        "test": "Wilcoxon signed-rank of ln(next/this), two-sided; equivalence: TOST",
        "pairs": len(differences),
        "median_difference": float(np.median(differences)) if differences else None,
        "median_difference_ci95": bootstrap_median(differences),
        "ratio": None if shift is None else math.exp(shift),
        "ratio_ci95": None if interval is None else (math.exp(interval[0]), math.exp(interval[1])),
        "p": p,
        "equivalence_p": equivalence,
        "shift": shift,
        "spread": float(np.std(logs, ddof=1)) if len(logs) > 1 else None,
    }


def sign_comparison(
    first: dict[Any, tuple[float, ...]], second: dict[Any, tuple[float, ...]], margin: float = MARGIN
) -> dict[str, Any]:
    """Two diagnoses on the runs both have (an outcome per run, lower is better): on how many runs
    ``second`` did worse and better, the two-sided sign test's p over the runs where they differ (1
    where they never do), and the p that they differ on fewer than a share ``margin`` of the runs."""
    from scipy.stats import binomtest

    runs = sorted(first.keys() & second.keys(), key=str)
    worse = sum(second[run] > first[run] for run in runs)
    better = sum(second[run] < first[run] for run in runs)
    p = float(binomtest(worse, worse + better).pvalue) if worse + better else 1.0
    equivalence = float(binomtest(worse + better, len(runs), margin, alternative="less").pvalue) if runs else 1.0
    return {
        "measure": "diagnosis",
        "test": "sign test (exact binomial), two-sided; equivalence: one-sided binomial",
        "pairs": len(runs),
        "worse": worse,
        "better": better,
        "p": p,
        "equivalence_p": equivalence,
    }


def _sign_runs_needed(worse: int, better: int, pairs: int, level: float) -> int | None:
    """About how many runs the sign test at ``level`` needs to separate the observed imbalance (the
    share of runs where the two differ, and how often one way) with power ``POWER``."""
    from scipy.stats import binom

    if worse == better or pairs == 0:
        return None
    q, differing = max(worse, better) / (worse + better), (worse + better) / pairs
    for m in range(fewest_pairs(level), MOST_RUNS):
        # reject when one side has at least c of the m differing runs, 2 P(X ≥ c | ½) ≤ level
        c = int(binom.isf(level / 2, m, 0.5)) + 1
        if 2 * binom.sf(c - 1, m, 0.5) > level:
            c += 1
        if c <= m and binom.sf(c - 1, m, q) + binom.cdf(m - c, m, q) >= POWER:
            return min(MOST_RUNS, math.ceil(m / differing))
        if m > 100_000:
            break
    return MOST_RUNS


def judge(comparisons: list[dict[str, Any]], margin: float = MARGIN, alpha: float = ALPHA) -> dict[str, Any]:
    """Holm-adjust the board's comparisons (difference tests and equivalence tests, each a family),
    give each its verdict and what its runs could tell; returns the board's summary of them."""
    level = alpha / len(comparisons) if comparisons else alpha
    for comparison, adjusted in zip(comparisons, holm([c["p"] for c in comparisons])):
        comparison["p_holm"] = adjusted
    for comparison, adjusted in zip(comparisons, holm([c["equivalence_p"] for c in comparisons])):
        comparison["equivalence_p_holm"] = adjusted
    for c in comparisons:
        separated = c["p_holm"] < alpha
        tied = not separated and c["equivalence_p_holm"] < alpha
        c["margin"] = margin
        c["verdict"] = SEPARATED if separated else TIED if tied else NOT_SEPARATED
        c["separated"], c["tied"] = separated, tied
        if c["measure"] == "diagnosis":  # what it detects: one scheme better on this many runs, never worse
            fewest = fewest_pairs(level)
            c["detectable_runs"] = None if fewest > c["pairs"] else fewest
            needed = _sign_runs_needed(c["worse"], c["better"], c["pairs"], level)
        else:
            c["detectable"] = detectable(c["pairs"], c.get("spread"), level)
            needed = runs_needed(c.get("shift"), c.get("spread"), level)
        c["needed"] = None if separated else needed
        # a difference seen in one run: its spread unknown, the test's fewest pairs at least
        c["needed_at_least"] = bool(not separated and needed is None and c.get("shift") and c.get("spread") is None)
        if c["needed_at_least"]:
            c["needed"] = max(2, fewest_pairs(level))
    count = {v: sum(c["verdict"] == v for c in comparisons) for v in (SEPARATED, TIED, NOT_SEPARATED)}
    return {
        "alpha": alpha,
        "power": POWER,
        "margin": margin,
        "comparisons": len(comparisons),
        "level": level,
        "separated": count[SEPARATED],
        "tied": count[TIED],
        "not_separated": count[NOT_SEPARATED],
    }
