"""Summarize a log.

Summarize a run log: channels and message counts, duration, scenario, frame counts, and per
estimator the RMS of |x - x̂| before and after the first fault, with units.
"""

from __future__ import annotations

import argparse

from cosim.cli import common


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", nargs="?", metavar="FILE.mcap", help=common.LOG_HELP + " (default)")
    p.add_argument("--json", action="store_true", help="print one JSON object (stable keys, for other tools)")


def main(args: argparse.Namespace) -> int:
    from cosim.analysis.summary import render, summarize

    report = summarize(common.latest_log(args.log))
    if args.json:
        common.print_json(report)
    else:
        render(report, common.console(wide=True))
    return 0
