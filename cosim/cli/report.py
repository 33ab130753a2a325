"""Write a self-contained HTML report of a log.

Write one HTML page about a run log: the scenario and its settings, the metrics of 'cosim inspect'
as tables, and the figures of 'cosim plot'. The page is self-contained (figures inlined, no network
needed) and reads on a laptop and on a phone.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cosim.cli import common


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", metavar="FILE.mcap", help=common.LOG_HELP)
    p.add_argument("--out", "-o", metavar="REPORT.html", help="output file (default: FILE.html next to the log)")


def main(args: argparse.Namespace) -> int:
    from cosim.analysis.report import report

    log = Path(common.latest_log(args.log))
    print(report(log, Path(args.out) if args.out else log.with_suffix(".html")))
    return 0
