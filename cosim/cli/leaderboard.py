"""Rank a campaign's estimators.

Rank the estimators of a campaign's results table per group of runs (the fault kind by default) by
their RMS error after onset: median with its 95 % interval, p90, final error, bias rejection,
detection rate, missed detections, false alarms per hour, detection and isolation delays, isolation
accuracy. Each estimator is compared with the next on their common runs (paired: median difference,
Wilcoxon signed-rank p, Holm-adjusted); ranks it cannot tell apart share their number (=).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from cosim.cli import common


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "results",
        nargs="+",
        metavar="RESULTS",
        help="a campaign's DIR/results.parquet, or the folders of one or more cosim benchmark bundles of the "
        "same suite (merged into one standing table)",
    )
    p.add_argument(
        "--by", nargs="+", metavar="COLUMN", help="group by these columns (default: fault_kind; bundles: track case)"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--html", metavar="FILE", help="also write a self-contained HTML page with figures and outliers")
    p.add_argument(
        "--exclude-contested",
        action="store_true",
        help="leave out the runs with contested ticks (another program sent on the runner's ids)",
    )
    p.add_argument("--markdown", action="store_true", help="print the tables as Markdown (for documents)")


def main(args: argparse.Namespace) -> int:
    from cosim.campaign.leaderboard import leaderboard

    results = args.results[0] if len(args.results) == 1 else args.results
    board = leaderboard(results, args.by, exclude_contested=args.exclude_contested)
    if args.html:
        from cosim.campaign.page import write_page

        common.error_console().print(f"wrote {escape(str(write_page(board, args.html)))}")
    if args.json:
        common.print_json(board)
        return 0
    render_leaderboard(board, common.console(wide=True), markdown=args.markdown)
    return 0


def _number(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"


def _percent(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f} %"


def _interval(bounds: Sequence[float | None] | None) -> str:
    return "-" if not bounds or bounds[0] is None else f"[{bounds[0]:.3g}, {bounds[1]:.3g}]"


def _versus(score: dict) -> str:
    """How an estimator compares with the next in its ranking, on their common runs."""
    comparison = score.get("vs_next")
    if not comparison:
        return ""
    sign = "=" if comparison["tied"] else ">"
    if comparison.get("metric") == "diagnosis":
        found = f"worse on {comparison['worse']}, better on {comparison['better']}"
    elif comparison.get("median_difference") is not None:
        found = f"{comparison['median_difference']:+.3g}"
    else:
        return ""
    return f"{sign} {found} p {comparison['p_holm']:.2g} ({comparison['pairs']})"


def leaderboard_rows(group: dict, unit: str) -> tuple[list[str], list[list[str]]]:
    """The headers and rows of one group of a leaderboard, as text."""
    diagnosis = any(s["diagnoses"] for s in group["ranking"])
    rms = f"RMS p50 [{unit}]" if unit else "RMS p50"
    headers = ["#", "estimator", "kind", "runs", rms, "95 % interval", "p90", "final p50", "peak p50"]
    headers += ["recovery p50 [s]", "rejection", "vs next"]
    if diagnosis:
        headers += ["detected", "missed", "false alarms/h", "delay p50 [s]", "isolation p50 [s]", "isolated right"]
    rows = []
    for s in group["ranking"]:
        cells = [
            f"{'=' if s.get('tied') else ''}{s['rank']}",
            s["estimator"],
            s["kind"],
            f"{s['runs']}" + (f" +{s['failed']}!" if s["failed"] else ""),
            _number(s["rms_post_fault_median"]),
            _interval(s.get("rms_post_fault_median_ci95")),
            _number(s["rms_post_fault_p90"]),
            _number(s.get("final_error_median")),
            _number(s.get("peak_error_median")),
            _number(s.get("recovery_time_median_s")),
            _number(s["bias_rejection_median"]),
            _versus(s),
        ]
        if diagnosis:
            cells += [
                _percent(s["detection_rate"]),
                str(s["missed_detections"] if s["missed_detections"] is not None else "-"),
                _number(s["false_alarms_per_hour"]),
                _number(s["detection_delay_median_s"]),
                _number(s["isolation_delay_median_s"]),
                _percent(s["isolation_accuracy"]),
            ]
        rows.append(cells)
    return headers, rows


LEGEND = (
    "RMS of the estimation error after the first fault's onset, median over runs with its 95 % bootstrap interval; "
    "final: the error at the last tick; peak: its largest after the onset; recovery: from the onset until it stays "
    "within twice its pre-fault level; vs next: > told apart from the next (=: not), the next estimator's median "
    "paired excess over this one on their common runs, Holm-adjusted Wilcoxon p and the number of pairs (two "
    "schemes that only diagnose: on how many runs the next diagnosed worse and better, Holm-adjusted sign test p); "
    "=2: a shared rank"
)


def confusion_lines(group: dict) -> list[str]:
    """Each diagnosis scheme's confusion matrix, true targets → isolated targets (runs)."""
    lines = []
    for s in group["ranking"]:
        if s.get("confusion"):
            cells = [f"{true} → {found} {n}" for true, row in s["confusion"].items() for found, n in row.items()]
            lines.append(f"{s['estimator']}, true → isolated (runs): {'; '.join(cells)}")
    return lines


def render_leaderboard(board: dict, talk: Console, markdown: bool = False) -> None:
    name = str(board.get("campaign") or board["table"])
    summary = f"{board['runs']} runs, {board['failed_runs']} failed; ranked per {', '.join(board['by'])}"
    if markdown:  # for documents: plain GitHub tables, one per group
        lines = [f"**{name}**: {summary}", ""]
        for group in board["groups"]:
            headers, rows = leaderboard_rows(group, group.get("unit", ""))
            lines += [", ".join(f"{k} = {v}" for k, v in group["group"].items()), ""]
            lines += ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
            lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
            lines += [*(f"- {line}" for line in confusion_lines(group)), ""] if confusion_lines(group) else []
        for track, schemes in board.get("tracks", {}).items():
            lines += [f"track = {track}: mean rank over its cases", "", "| estimator | kind | mean rank | cases |"]
            lines += ["|---|---|---|---|"] + [
                f"| {s['estimator']} | {s['kind']} | {s['mean_rank']:.2f} | {s['cases']} |" for s in schemes
            ]
            lines.append("")
        sys.stdout.write("\n".join([*lines, LEGEND, ""]))
        return
    talk.print(f"[bold]{escape(name)}[/bold]: {summary}")
    for group in board["groups"]:
        title = ", ".join(f"{k} = {v}" for k, v in group["group"].items())
        table = Table(title=escape(title), title_justify="left", box=None, header_style="bold")
        headers, rows = leaderboard_rows(group, group.get("unit", ""))
        for i, header in enumerate(headers):
            table.add_column(escape(header), justify="left" if 0 < i < 3 or header == "vs next" else "right")
        for row in rows:
            table.add_row(*map(escape, row))
        talk.print(table)
        for line in confusion_lines(group):
            talk.print(f"  {escape(line)}")
    for track, schemes in board.get("tracks", {}).items():
        table = Table(title=f"track {escape(track)}: mean rank over its cases", title_justify="left", box=None)
        for header in ("estimator", "kind", "mean rank", "cases"):
            table.add_column(header, justify="right" if header in ("mean rank", "cases") else "left")
        for s in schemes:
            table.add_row(escape(s["estimator"]), escape(s["kind"]), f"{s['mean_rank']:.2f}", str(s["cases"]))
        talk.print(table)
    if "benchmark" in board:
        b = board["benchmark"]
        selection = "quick" if b["quick"] else "full"
        suite = f"{escape(b['suite'])} v{b['version']} ({selection}, digest {b['digest'][:12]})"
        talk.print(f"suite {suite}, {b['bundles']} bundles")
    talk.print(f"[dim]{escape(LEGEND)}[/dim]")
    if board["outliers"]:
        talk.print(f"{len(board['outliers'])} outliers and failed runs: see --json or --html")
