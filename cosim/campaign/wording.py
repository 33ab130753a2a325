"""How a leaderboard reads, the same in its text, Markdown and HTML forms: rounded numbers and
intervals, rank labels, what a group pooled, and each verdict in words with what its runs could
tell (``cosim.campaign.verdicts``)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from cosim.campaign.verdicts import MOST_RUNS, SEPARATED, TIED


def number(value: Any, digits: int = 3) -> str:
    """A number rounded to ``digits`` significant digits, below 0.001 and from 10⁶ with a short
    exponent (``8.75e-5``); – for none."""
    if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return "–"
    if isinstance(value, float) and not math.isfinite(value):
        return "–"
    if isinstance(value, int):
        text = str(value)
    elif value != 0 and not 1e-3 <= abs(value) < 1e6:
        text = f"{value:.{digits - 1}e}"
    else:
        text = f"{value:.{digits}g}"
    mantissa, e, exponent = text.partition("e")
    if e and "." in mantissa:
        mantissa = mantissa.rstrip("0").rstrip(".")
    return f"{mantissa}e{int(exponent)}" if e else text


def interval(bounds: Sequence[float | None] | None, digits: int = 3) -> str:
    """A 95 % interval rounded to ``digits`` significant digits: ``[0.151, 0.252]``; empty for none."""
    if not bounds or bounds[0] is None or bounds[1] is None:
        return ""
    return f"[{number(bounds[0], digits)}, {number(bounds[1], digits)}]"


def with_interval(value: Any, bounds: Sequence[float | None] | None) -> str:
    return f"{number(value)} {interval(bounds)}".rstrip()


def pct(value: float | None) -> str:
    """A proportion as a percentage: ``95 %``, ``33.3 %``; – for none."""
    return "–" if value is None else f"{number(100 * value)} %"


def pct_interval(bounds: Sequence[float] | None) -> str:
    return "" if not bounds else f"[{number(100 * bounds[0])}, {number(100 * bounds[1])}]"


def duration(value: float | None) -> str:
    """A time: ``10.4 s``; – for none."""
    return "–" if value is None else f"{number(value)} s"


def seconds(median: float | None, p90: float | None) -> str:
    """A median and 90th percentile of a time: ``0.15 / 0.2 s``; – for none."""
    return "–" if median is None else f"{number(median)} / {number(p90)} s"


def scheme(score: dict[str, Any]) -> str:
    """A scheme by its name, and its kind where that is another (``extra (kalman)``)."""
    kind = score.get("kind_name") or score.get("kind") or ""
    return score["estimator"] if kind in ("", score["estimator"]) else f"{score['estimator']} ({kind})"


def rank(score: dict[str, Any]) -> str:
    """``1``; ``=2`` where it shares its rank with a scheme shown equivalent; ``~2`` where it shares
    it with one it is not separated from; – where nothing ranks it."""
    if score.get("rank") is None:
        return "–"
    mark = "" if not score.get("shared") else "=" if score.get("settled") else "~"
    return f"{mark}{score['rank']}"


def group_title(group: dict[str, Any]) -> str:
    return ", ".join(f"{key} = {value}" for key, value in group["group"].items()) or "all runs"


def not_run(group: dict[str, Any]) -> str:
    """A group no scheme was scored in, and why: ``not run: its 4 runs failed before any scheme ran: ...``."""
    why = group.get("not_run")
    if not why:
        return ""
    runs = "its run" if why["runs"] == 1 else f"its {why['runs']} runs"
    return f"not run: {runs} failed before any scheme ran: {why['why']}"


def pooled(group: dict[str, Any]) -> str:
    """What a group pooled: ``pooled over bias_m (2 values), sensor (3); sampled onset (12)``."""
    axes = [p for p in group.get("pooled", []) if not p["sampled"]]
    samples = [p for p in group.get("pooled", []) if p["sampled"]]
    parts = []
    if axes:
        parts.append("pooled over " + ", ".join(f"{p['column']} ({p['values']} values)" for p in axes))
    if samples:
        parts.append("over the sampled " + ", ".join(f"{p['column']} ({p['values']} values)" for p in samples))
    return "; ".join(parts)


def relative(ratio: float, times: bool | None = None) -> str:
    """A ratio of errors as a change: ``+3.1 %``, ``−12 %``, or as a factor, ``×70``, ``×0.17``;
    ``times`` chooses the form (None: a factor from ×2 or to ×0.5)."""
    if times is None:
        times = as_factors([ratio])
    if times:
        return f"×{number(ratio, 2)}"
    change = 100 * (ratio - 1)
    text = number(abs(change), 2)
    return f"{'+' if change >= 0 else '−'}{text} %"


def as_factors(ratios: Sequence[float | None]) -> bool:
    """Whether ratios shown together read as factors (one of them from ×2 or to ×0.5) rather than as
    percentages: one form for a line, never ``×0.17 [×0.14, +25 %]``."""
    return any(r is not None and (r >= 2 or r <= 0.5) for r in ratios)


def _runs(n: int) -> str:
    return f"{n} run{'' if n == 1 else 's'}"


def detectable(comparison: dict[str, Any], level: float, times: bool | None = None) -> str:
    """What the runs of a comparison could detect (at the board's level, power 0.8), as a factor or
    a percentage as ``times`` says (None: as its size asks)."""
    c = comparison
    if c["measure"] == "diagnosis":
        if c["detectable_runs"] is None:
            return f"{_runs(c['pairs'])} can separate nothing at α' = {level:.2g}"
        return f"detectable: one better on {c['detectable_runs']} runs, never worse"
    if c["detectable"] is None:
        return f"{_runs(c['pairs'])} can separate nothing at α' = {level:.2g}"
    if c["detectable"] < 1e-4 and not times:
        return "detectable ≥ 0.01 %"
    return f"detectable ≥ {relative(1 + c['detectable'], times).removeprefix('+')}"


def verdict(comparison: dict[str, Any], level: float) -> str:
    """A comparison with the next scheme in words: the next's difference, the verdict, and what the
    runs could tell: ``> kalman: error +21 % [+15, +30 %], p 0.001: separated; detectable ≥ 8 %``;
    every ratio of the line in one form, factors where one of them is from ×2 or to ×0.5
    (``error ×5.6 [×4.1, ×7.5] ...; detectable ≥ ×1.2``)."""
    c, following = comparison, comparison["estimator"]
    ratios = [c.get("ratio"), *(c.get("ratio_ci95") or [])]
    if c["measure"] != "diagnosis" and c.get("detectable") is not None:
        ratios.append(1 + c["detectable"])
    times = as_factors(ratios)
    if c["measure"] == "diagnosis":
        found = f"{following}: worse on {c['worse']}, better on {c['better']} of {_runs(c['pairs'])}"
    elif c.get("ratio") is None:
        found = f"{following}: no runs in common"
    else:
        found = f"{following}: error {relative(c['ratio'], times)}"
        if c.get("ratio_ci95"):
            low, high = c["ratio_ci95"]
            found += f" [{relative(low, times)}, {relative(high, times)}]"
    could = detectable(c, level, times)
    if c["verdict"] == SEPARATED:
        return f"> {found}, p {c['p_holm']:.2g}: separated; {could}"
    if c["verdict"] == TIED:
        margin = number(100 * c["margin"], 2)
        return f"= {found}: tied within ±{margin} % (p {c['equivalence_p_holm']:.2g}); {could}"
    needed = c.get("needed")
    if needed is None:
        about = "no difference seen"
    elif needed >= MOST_RUNS:
        about = f"over {MOST_RUNS:.0e} needed"
    elif c.get("needed_at_least"):  # one run: its spread unknown
        about = f"at least {needed} needed"
    else:
        about = f"about {needed} needed"
    return f"~ {found}: not separated ({_runs(c['pairs'])}; {about}); {could}"


def diagnosis(score: dict[str, Any]) -> str:
    """A scheme's diagnosis in one line: detection, misses, false alarms, delays, isolation."""
    s = score
    parts = [
        f"detected {pct(s['detection_rate'])} {pct_interval(s['detection_rate_ci95'])}".rstrip(),
        f"missed {number(s['missed_detections'])}",
        f"false alarms/h {with_interval(s['false_alarms_per_hour'], s['false_alarms_per_hour_ci95'])}",
        f"delay {seconds(s['detection_delay_median_s'], s['detection_delay_p90_s'])}",
        f"isolation {seconds(s['isolation_delay_median_s'], s['isolation_delay_p90_s'])}",
        f"isolated right {pct(s['isolation_accuracy'])} {pct_interval(s['isolation_accuracy_ci95'])}".rstrip(),
    ]
    return " · ".join(part for part in parts if not part.endswith("–")) or "no diagnosis scored"


def summary(board: dict[str, Any]) -> str:
    """The board's verdicts in one sentence."""
    v = board["verdicts"]
    if not v["comparisons"]:
        return "No comparisons: no two schemes share a measure and runs."
    count = f"{v['comparisons']} comparison{'' if v['comparisons'] == 1 else 's'}"
    return (
        f"{count} at α = {v['alpha']:g} (Holm; a p below α' = α/{v['comparisons']} = "
        f"{v['level']:.2g} separates whatever the others): {v['separated']} separated, {v['tied']} tied within "
        f"±{number(100 * v['margin'], 2)} %, {v['not_separated']} not separated."
    )


def track_rank(scheme_rank: dict[str, Any]) -> str:
    """A scheme's mean rank in a track: ``1.50 over 2 of 5 cases``; – where no case places it."""
    t = scheme_rank
    mean = "–" if t["mean_rank"] is None else f"{t['mean_rank']:.2f}"
    return f"{mean} over {t['placed']} of {t['cases']} case{'' if t['cases'] == 1 else 's'}"


LEGEND = (
    "RMS: the estimation error after the first fault's onset, median over the runs [95 % bootstrap interval] "
    "and 90th percentile; final, peak, recovery: medians of the error at the last tick, of its largest after the "
    "onset, and of the time until it stays within twice its pre-fault level. Each scheme is compared with the "
    "next on their common runs (paired: the same noise and faults): the next's error as a change (the "
    "Hodges–Lehmann estimate of the per-run ratio) [95 % interval]; "
    "> separated (Wilcoxon signed-rank test of the log ratios, Holm-adjusted p < α), = tied (shown equivalent "
    "within the margin, TOST), ~ not separated (with about how many runs would separate a difference of the "
    "size seen); detectable: the smallest difference these runs detect with power 0.8. Schemes that only "
    "diagnose: on how many runs the next diagnosed worse and better, by the sign test. Rank: 1 + the schemes "
    "shown better; =2 shared with an equivalent scheme, ~2 with one not separated (docs/benchmark.md)."
)
