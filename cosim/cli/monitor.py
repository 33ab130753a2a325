"""Show a bus's decoded signals live.

Show decoded signals live, message by message: of a running co-simulation (the only one, or --run
ID, printed by 'cosim run'), or of any bus with --dbc (a bench, 'cosim replay --live', a log written
by another tool).

On a terminal: a table of every message's latest values. Piped or redirected: a line per decoded
message as it comes (message, sender, tick, signals; with --dbc the seconds since the start, then
message, id, senders, signals), what is watched and the frame count on standard error.
"""

from __future__ import annotations

import argparse

from cosim.cli import common

EPILOG = (
    "examples:\n  cosim monitor\n  cosim monitor --run 3f2a\n"
    "  cosim monitor --dbc bus.dbc --interface socketcan --channel vcan0\n"
    "  cosim monitor --dbc bus.dbc --channel 239.74.163.2 --port 43113\n"
    "  cosim monitor | grep EST_kalman > kalman.txt"
)


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--run", metavar="ID", help="which running co-simulation (default: the only one)")
    p.add_argument("--dbc", metavar="FILE.dbc", help="decode any bus with this database (with --interface, --channel)")
    common.bus_options(p, "udp_multicast, with --dbc")


def main(args: argparse.Namespace) -> int:
    from cosim.bus import monitor

    if args.dbc is None:
        common.refuse(args, ("--interface", "--channel", "--port"), "only with --dbc (a run's bus is found by --run)")
        return monitor.monitor(args.run, common.console())
    common.refuse(args, ("--run",), "not with --dbc, which watches the bus --interface and --channel name")
    return monitor.watch(args.dbc, args.interface or "udp_multicast", args.channel, args.port, common.console())
