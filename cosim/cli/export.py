"""Export a log for other tools (CSV, Parquet, BLF, ASC, TRC, MF4, candump, ROS 2 bag).

Export a run log for the tools engineers already use. The log is streamed: any length fits in
memory.

tables, one row per tick, columns tick, 't [s]' (simulated time), then '<topic>.<field> [unit]' for the
truth and the decoded bus signals (state.x1 [m], faults.measured.x2 [m], EST_kalman.xhat_v1 [m/s], ...);
of a log 'cosim import' wrote, one row per decoded frame: 'time [ns]', 't [s]', message, its signals:
  csv       text; floats as the shortest decimal that reads back exactly
  parquet   columnar, units and source topic in each field's metadata
raw CAN frames, every frame on the bus, timestamped with simulated time:
  blf       Vector binary log (CANalyzer, CANoe, python-can)
  asc       Vector ASCII log (CANalyzer, CANoe, SavvyCAN, python-can)
  trc       PEAK trace, version 2.1 (PCAN-View, PCAN-Explorer; classic CAN only)
  mf4       ASAM MDF4 bus log, CAN_DataFrame layout, the DBC attached (asammdf, CANalyzer)
  candump   text log of 'candump -L': (t) can0 ID#DATA, ID##<flags>DATA for CAN FD (can-utils,
            SavvyCAN, cantools, python-can)
a ROS 2 bag, stamped as the frame logs:
  rosbag2   a rosbag2 folder (MCAP storage, CDR; ros2 bag, rosbags, Foxglove): the frames on
            /can/frames as can_msgs/msg/Frame (CAN FD: /can/frames_fd, ros2_socketcan_msgs/msg/FdFrame),
            every other topic (truth, decoded signals, estimates) as a cosim_msgs message whose
            fields are its signals, units in the definitions' comments (embedded in the bag)

Decode frames with the DBC from 'cosim dbc SCENARIO' (the MF4 file carries it).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cosim.cli import common
from cosim.errors import CosimError

EPILOG = (
    "examples:\n  cosim export runs/my.mcap --to csv\n  cosim export runs/my.mcap --to mf4 --out bus.mf4\n"
    "  cosim export latest --to asc\n"
    "  cosim export runs/my.mcap --to rosbag2 --out my_bag    then: ros2 bag info my_bag"
)


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", metavar="FILE.mcap", help=common.LOG_HELP)
    p.add_argument("--to", required=True, choices=EXPORT_FORMATS, help="output format")
    p.add_argument(
        "--out",
        "-o",
        metavar="PATH",
        help="output file (default: FILE.csv, .parquet, .blf, .asc, .trc, .mf4 or .log next to the log); rosbag2: "
        "the bag's folder (default: FILE without .mcap)",
    )
    common.force_option(p)
    p.add_argument(
        "--dbc", metavar="FILE.dbc", help="mf4 only: the DBC to attach, for a log that has none (default: the log's)"
    )
    p.add_argument(
        "--start-time",
        metavar="WHEN",
        help="frame logs and bags: the wall-clock time of tick 0, an ISO 8601 date and time (2025-06-01T12:00:00Z; UTC "
        "without a zone) or seconds since the Unix epoch; 0: the epoch (t = 0 s) (default: when the run started, "
        "to the millisecond)",
    )


def main(args: argparse.Namespace) -> int:
    from datetime import UTC, datetime

    from cosim.analysis.export import FRAME_FORMATS, default_output, export, parse_start_time

    log = common.latest_log(args.log)
    out = common.unused(Path(args.out) if args.out else default_output(log, args.to), args.force)
    if args.to == "rosbag2" and out.exists() and not args.force:
        raise CosimError(f"{out} exists: choose another --out, or pass --force to replace it")
    start = None if args.start_time is None else parse_start_time(args.start_time)
    result = export(log, args.to, out, dbc=args.dbc, start_ns=start)
    talk = common.error_console()
    common.warn(talk, result.warnings)
    stamped = ""
    if args.to in FRAME_FORMATS and result.start_ns is not None:
        when = datetime.fromtimestamp(result.start_ns / 1e9, UTC)
        stamped = f", {result.start_of} at {when.isoformat(timespec='milliseconds').replace('+00:00', 'Z')}"
    talk.print(f"wrote {result.count} {result.what} as {args.to}{stamped}")
    print(result.path)
    return 0


#: ``cosim.analysis.export.FORMATS``, without importing the export at every start of the command line
#: (tests/test_export.py checks that they agree).
EXPORT_FORMATS = ("csv", "parquet", "blf", "asc", "trc", "mf4", "candump", "rosbag2")
