"""Import another tool's CAN log, decoded by its DBC, as an MCAP log.

Import a CAN log written by another tool (candump -L .log, Vector BLF and ASC, PEAK TRC, ASAM MF4
bus logging, python-can's .csv and .db) and decode it by its DBC into an MCAP log: every frame on
/can/frames, every DBC message on a topic of its own (/can/<Message>) with its signals' units in
JSON Schemas, each message at the frame's recorded time, the DBC attached. Open it in Foxglove
(with 'cosim layout' for a plot per message), or use it with 'cosim inspect', 'plot', 'export' and
'replay --live'.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.markup import escape

from cosim.cli import common

NAME = "import"
EPILOG = """\
examples:
  cosim import drive.blf --dbc car.dbc --out drive.mcap
  cosim import candump-2024-06-01.log --dbc car.dbc      (writes candump-2024-06-01.mcap)
  cosim layout drive.mcap --out drive.layout.json        a plot per message, for Foxglove"""


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", metavar="LOG", help="the CAN log: .log (candump -L), .blf, .asc, .trc, .mf4, .csv or .db")
    p.add_argument("--dbc", required=True, metavar="FILE.dbc", help="the CAN database that decodes its frames")
    p.add_argument("--out", "-o", metavar="FILE.mcap", help="the MCAP log to write (default: LOG with .mcap)")
    common.force_option(p)
    common.quiet_option(p)


def main(args: argparse.Namespace) -> int:
    from cosim.log.can_import import import_log

    log = Path(args.log)
    out = common.unused(Path(args.out) if args.out else log.with_suffix(".mcap"), args.force)
    result = import_log(log, args.dbc, out)
    talk = common.console(stderr=True, quiet=args.quiet)
    common.warn(talk, result.warnings)
    record = result.record
    span = ((record.end_time_ns or 0) - (record.start_time_ns or 0)) / 1e9
    talk.print(
        f"imported {record.frames} frames ({span:g} s of {record.format}): {record.decoded} decoded into "
        f"{len(result.topics)} messages by {escape(record.dbc)}"
    )
    print(result.path)
    return 0
