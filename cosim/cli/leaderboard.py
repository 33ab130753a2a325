"""Rank a campaign's estimators.

Rank the estimators of a campaign's results table (or of cosim benchmark bundles) per group of
runs (every axis the campaign swept; --by groups by other columns and pools the rest, which each
group names) by their RMS error after onset: median with its 95 % interval, p90, final and peak
error, recovery, and for diagnosis schemes detection, false alarms, delays and isolation. Each
scheme is compared with the next on their common runs (paired): separated, tied within a margin,
or not separated, with the smallest difference its runs could detect and, when not separated,
about how many runs would separate the difference seen.
"""

from __future__ import annotations

import argparse
import re
import sys
import textwrap
from typing import Any

from rich.console import Console
from rich.markup import escape

from cosim.campaign import wording
from cosim.cli import common

WIDTH = 100
"""The text board's width: its rows stack onto more lines rather than run wider."""


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "results",
        nargs="+",
        metavar="RESULTS",
        help="a campaign's DIR/results.parquet, or the folders of one or more cosim benchmark bundles of the "
        "same suite (merged into one standing table)",
    )
    p.add_argument(
        "--by",
        nargs="+",
        metavar="COLUMN",
        help="group by these columns and pool the campaign's other axes (default: every axis it swept; "
        "bundles: track case)",
    )
    p.add_argument(
        "--margin",
        type=float,
        default=5.0,
        metavar="PERCENT",
        help="equivalence margin: two schemes are tied when shown to differ by less than this (default 5 %%)",
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
    from cosim.errors import CosimError
    from cosim.extras import require_all

    require_all(
        "cosim leaderboard" + (" --html" if args.html else ""),
        {"campaign": ["pyarrow"]} | ({"plot": ["matplotlib"]} if args.html else {}),
    )
    if not 0 < args.margin < 100:
        raise CosimError(f"--margin {args.margin:g}: give a percentage between 0 and 100, e.g. --margin 5")
    results = args.results[0] if len(args.results) == 1 else args.results
    board = leaderboard(results, args.by, exclude_contested=args.exclude_contested, margin=args.margin / 100)
    if args.html:
        from cosim.campaign.page import write_page

        common.error_console().print(f"wrote {escape(str(write_page(board, args.html)))}")
    if args.json:
        common.print_json(board)
    elif args.markdown:
        sys.stdout.write(markdown(board))
    else:
        render_leaderboard(board, common.console(wide=True))
    return 0


def heading(board: dict[str, Any]) -> list[str]:
    """What the board ranks, how, and whether its verdicts are only indicative."""
    name = str(board.get("campaign") or board["table"])
    lines = [f"{name}: {board['runs']} runs, {board['failed_runs']} failed; ranked per {', '.join(board['by'])}"]
    if "benchmark" in board:
        b = board["benchmark"]
        selection = "quick selection" if b["quick"] else "full suite"
        bundles = f"{b['bundles']} bundle{'s' if b['bundles'] != 1 else ''}"
        lines.append(f"suite {b['suite']} v{b['version']} ({selection}, digest {b['digest'][:12]}), {bundles}")
    if board.get("indicative"):
        lines.append(f"INDICATIVE ONLY: {board['indicative']}")
    return [*lines, wording.summary(board)]


#: What a line never breaks: an interval, a number and its unit.
UNBROKEN = re.compile(r"\[[^\]]*\]|\d \S*%|\d s\b|\d /h\b|α' = \S+")


def _wrapped(text: str, indent: int, hang: int = 2) -> list[str]:
    """``text`` wrapped at ``WIDTH``, its intervals and numbers with their units kept whole."""
    kept = UNBROKEN.sub(lambda found: found.group().replace(" ", "\0"), text)
    lines = textwrap.wrap(
        kept, WIDTH, initial_indent=" " * indent, subsequent_indent=" " * (indent + hang), break_on_hyphens=False
    )
    return [line.replace("\0", " ") for line in lines]


def estimator_lines(group: dict[str, Any], level: float) -> list[str]:
    """The estimators of a group, a block each: rank, scheme, runs and errors on one line (the
    scheme's name on a line of its own where it is long), its diagnosis and its verdict below."""
    ranked = [s for s in group["ranking"] if s.get("chain") == "estimation"]
    if not ranked:
        return []
    unit = f" [{group['unit']}]" if group.get("unit") else ""
    cells = [
        [
            wording.rank(s),
            wording.scheme(s),
            f"{s['runs']}" + (f"+{s['failed']}!" if s["failed"] else ""),
            wording.with_interval(s["rms_post_fault_median"], s.get("rms_post_fault_median_ci95")),
            wording.number(s["rms_post_fault_p90"]),
            wording.number(s.get("final_error_median")),
            wording.number(s.get("peak_error_median")),
            wording.duration(s.get("recovery_time_median_s")),
        ]
        for s in ranked
    ]
    headers = ["#", "scheme", "runs", f"RMS p50 [95 %]{unit}", "p90", "final", "peak", "recovery"]
    name_width = min(26, max(len(headers[1]), *(len(c[1]) for c in cells)))
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, h in enumerate(headers)]
    widths[1] = name_width

    columns = len(headers)

    def line(row: list[str]) -> str:
        rank, name = (row[0], row[1]) if len(row[1]) <= name_width else ("", "")
        parts = [rank.rjust(widths[0]), name.ljust(name_width), row[2].rjust(widths[2])]
        parts += [cell.ljust(width) for cell, width in zip(row[3:columns], widths[3:columns])]
        return " ".join(parts).rstrip()

    if any(len(line(row)) > WIDTH for row in [headers, *cells]):  # final, peak and recovery stacked below
        columns = 5
    lines = [line(headers)]
    indent = widths[0] + 1
    for score, row in zip(ranked, cells):
        if len(row[1]) > name_width:  # a long name stacks above its numbers
            lines += _wrapped(f"{row[0].rjust(widths[0])} {row[1]}", 0, indent)
        lines.append(line(row))
        if columns < len(headers):
            lines += _wrapped(" · ".join(f"{h} {c}" for h, c in zip(headers[columns:], row[columns:])), indent)
        if score["diagnoses"]:
            lines += _wrapped(wording.diagnosis(score), indent)
        if score.get("vs_next"):
            lines += _wrapped(wording.verdict(score["vs_next"], level), indent)
    return lines


def diagnosis_lines(group: dict[str, Any], level: float) -> list[str]:
    """The schemes that only diagnose, ranked among themselves: a block each."""
    ranked = [s for s in group["ranking"] if s.get("chain") == "diagnosis"]
    lines = ["schemes that only diagnose, ranked among themselves:"] if ranked else []
    for s in ranked:
        runs = f"{s['runs']} runs" + (f" +{s['failed']} failed" if s["failed"] else "")
        lines += _wrapped(f"{wording.rank(s)} {wording.scheme(s)}, {runs}: {wording.diagnosis(s)}", 1, 4)
        if s.get("vs_next"):
            lines += _wrapped(wording.verdict(s["vs_next"], level), 4)
    unranked = [s for s in group["ranking"] if s.get("chain") is None]
    if unranked:
        names = ", ".join(f"{wording.scheme(s)} ({s['runs']} runs)" for s in unranked)
        lines += _wrapped(f"not ranked (no error after an onset, no diagnosis): {names}", 1, 4)
    return lines


def confusion_lines(group: dict[str, Any]) -> list[str]:
    """Each diagnosis scheme's confusion matrix, true targets → isolated targets (runs)."""
    lines = []
    for s in group["ranking"]:
        if s.get("confusion"):
            cells = [f"{true} → {found} {n}" for true, row in s["confusion"].items() for found, n in row.items()]
            lines += _wrapped(f"{s['estimator']}, true → isolated (runs): {'; '.join(cells)}", 1, 4)
    return lines


def track_lines(board: dict[str, Any]) -> list[str]:
    lines = []
    for track, schemes in board.get("tracks", {}).items():
        lines += ["", f"track {track}: mean rank over the cases whose comparisons place each scheme"]
        width = max(len(wording.scheme(s)) for s in schemes)
        lines += [f"  {wording.scheme(s).ljust(width)}  {wording.track_rank(s)}" for s in schemes]
        unplaced = sum(s["cases"] - s["placed"] for s in schemes)
        if unplaced:
            lines += _wrapped(
                f"{unplaced} places not counted: the scheme was alone or not separated from a neighbour", 2
            )
    return lines


def text_lines(board: dict[str, Any]) -> list[str]:
    """The whole board as lines of at most ``WIDTH`` characters."""
    level = board["verdicts"]["level"]
    lines = [line for text in heading(board) for line in _wrapped(text, 0)]
    for group in board["groups"]:
        title = wording.group_title(group)
        lines += ["", *_wrapped(title + (f" · {wording.pooled(group)}" if group.get("pooled") else ""), 0)]
        lines += _wrapped(wording.not_run(group), 1, 4) if group.get("not_run") else []
        lines += estimator_lines(group, level) + diagnosis_lines(group, level) + confusion_lines(group)
    lines += track_lines(board)
    lines += ["", *_wrapped(wording.LEGEND, 0, 0)]
    if board["outliers"]:
        lines.append(f"{len(board['outliers'])} outliers and failed runs: see --json or --html")
    return lines


def render_leaderboard(board: dict[str, Any], talk: Console) -> None:
    for line in text_lines(board):
        talk.print(escape(line))


def markdown(board: dict[str, Any]) -> str:
    """The board as Markdown (for documents): a table per group, the verdicts in a column."""
    level = board["verdicts"]["level"]
    lines = [f"**{text}**" if i == 0 else text for i, text in enumerate(heading(board))]
    lines = [line + "  " for line in lines[:-1]] + lines[-1:]
    for group in board["groups"]:
        lines += ["", f"*{wording.group_title(group)}*" + (f" ({wording.pooled(group)})" if group["pooled"] else "")]
        if group.get("not_run"):
            lines += ["", wording.not_run(group)]
            continue
        unit = f" [{group['unit']}]" if group.get("unit") else ""
        diagnoses = any(s["diagnoses"] for s in group["ranking"])
        headers = ["#", "scheme", "runs", f"RMS p50 [95 %]{unit}", "p90", "final", "peak", "recovery [s]"]
        headers += ["diagnosis"] if diagnoses else []
        lines += ["", "| " + " | ".join(headers + ["vs next"]) + " |", "|" + "---|" * (len(headers) + 1)]
        for s in group["ranking"]:
            cells = [
                wording.rank(s),
                wording.scheme(s),
                str(s["runs"]) + (f" +{s['failed']} failed" if s["failed"] else ""),
                wording.with_interval(s["rms_post_fault_median"], s.get("rms_post_fault_median_ci95")),
                wording.number(s["rms_post_fault_p90"]),
                wording.number(s.get("final_error_median")),
                wording.number(s.get("peak_error_median")),
                wording.number(s.get("recovery_time_median_s")),
            ]
            cells += [wording.diagnosis(s) if s["diagnoses"] else "–"] if diagnoses else []
            cells.append(wording.verdict(s["vs_next"], level) if s.get("vs_next") else "")
            lines.append("| " + " | ".join(cell.replace("|", "\\|") for cell in cells) + " |")
        lines += [f"- {line.strip()}" for line in confusion_lines(group)]
    for track, schemes in board.get("tracks", {}).items():
        lines += ["", f"*track {track}: mean rank over the cases whose comparisons place each scheme*", ""]
        lines += ["| scheme | mean rank |", "|---|---|"]
        lines += [f"| {wording.scheme(s)} | {wording.track_rank(s)} |" for s in schemes]
    return "\n".join([*lines, "", wording.LEGEND, ""])
