"""Rebuild a log whose writer died (summary, indexes).

Rebuild the summary and indexes of a log whose writer died (a runner killed with SIGKILL, a full
disk): its records are read in order, CRCs checked, up to the first damaged one, and written into a
complete MCAP file that every reader opens (mcap's make_reader, @mcap/core, Foxglove). A record
'cosim.recovered' says what was found. Without --out the log is replaced, once the new file is
complete.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.markup import escape

from cosim.cli import common


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", metavar="FILE.mcap")
    p.add_argument("--out", "-o", metavar="FIXED.mcap", help="write the recovered log here instead of replacing FILE")
    common.force_option(p)


def main(args: argparse.Namespace) -> int:
    from cosim.log.recover import recover

    if args.out:
        common.unused(Path(args.out), args.force)
    result = recover(args.log, args.out)
    talk = common.error_console()
    talk.print(
        f"recovered {result.messages} messages on {result.channels} channels, {result.metadata} metadata records and "
        f"{result.attachments} attachments (to t = {(result.last_time_ns or 0) / 1e9:g} s)"
    )
    if result.damage:
        talk.print(f"[yellow]{escape(result.damage)}[/yellow]")
    common.warn(talk, result.warnings)
    print(result.path)
    return 0
