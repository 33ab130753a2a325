"""Write the CAN database of a scenario.

Write the DBC database of a scenario's bus, so that external tools can decode its frames.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cosim.cli import common


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", nargs="?", metavar="SCENARIO", help=f"{common.SCENARIO_HELP} (default: masses-bias)")
    p.add_argument("--out", "-o", metavar="FILE.dbc", help="output file (default: standard output)")
    common.set_option(p)


def main(args: argparse.Namespace) -> int:
    text = common.load_scenario(args.scenario, args.set).scenario.codec().dbc
    if args.out:
        Path(args.out).write_text(text)
        common.error_console().print(f"wrote {args.out}")
    else:
        sys.stdout.write(text)
    return 0
