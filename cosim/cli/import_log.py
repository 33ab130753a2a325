"""Import another tool's CAN log or a ROS 2 bag, decoded by its DBC, as an MCAP log.

Import a CAN log written by another tool (candump -L .log, Vector BLF and ASC, PEAK TRC, ASAM MF4
bus logging, python-can's .csv and .db), or the CAN topics of a ROS 2 bag (a rosbag2 folder, MCAP
or SQLite, or one .mcap or .db3 of one: can_msgs/msg/Frame and ros2_socketcan_msgs/msg/FdFrame, as
ros2_socketcan records them), and decode it by its DBC into an MCAP log: every frame on
/can/frames, every DBC message on a topic of its own (/can/<Message>) with its signals' units in
JSON Schemas, each message at the frame's recorded time, the DBC attached. Open it in Foxglove
(with 'cosim layout' for a plot per message), or use it with 'cosim inspect', 'plot', 'export' and
'replay --live'. A log of several buses (channels) is decoded whole by the one DBC unless --channel
picks one (a bag's: --topic); each frame's channel (a bag's topic) is on /can/frames, with a bag's
header stamp. A signal with a value table is logged as its number; its schema names the values. A
J1939 DBC's parameter groups decode frames of any source address by their PGN, the address kept in
each message's source_address.

Times are kept as the log writes them (a text log's to the last digit; BLF, MF4 and SQLite to the
microsecond, as python-can reads them; a bag's to the nanosecond). candump, MF4, python-can's logs
and ROS 2 bags record UTC; Vector's ASC and BLF and PEAK's TRC record the local time of the PC that
recorded them, with no zone: they are logged as they read, as if they were UTC, and the log and its
figures say that the zone is unknown, unless --timezone names it (then they are converted to UTC). A
line of a text log (candump, ASC, TRC, CSV) that is not a frame is skipped and counted, the first
named by its line number; a file that is mostly not a log is refused.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.markup import escape

from cosim.cli import common
from cosim.errors import CosimError

NAME = "import"
EPILOG = """\
examples:
  cosim import drive.blf --dbc car.dbc --out drive.mcap
  cosim import candump-2024-06-01.log --dbc car.dbc      (writes candump-2024-06-01.mcap)
  cosim import drive.blf --channel 2 --dbc body.dbc --out body.mcap   one bus of a log of several
  cosim import rosbag2_2024_06_01/ --dbc car.dbc --out drive.mcap      a ROS 2 bag (ros2_socketcan)
  cosim import rosbag2_2024_06_01/ --topic /from_can_bus --dbc car.dbc   one topic of the bag
  cosim import trace.trc --dbc car.dbc --timezone Europe/Berlin   a PEAK trace recorded in Germany
  cosim layout drive.mcap --out drive.layout.json        a plot per message, for Foxglove"""


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "log",
        metavar="LOG",
        help="the CAN log: .log (candump -L), .blf, .asc, .trc, .mf4, .csv or .db; or a ROS 2 bag: a rosbag2 "
        "folder, or one .mcap or .db3 of one",
    )
    p.add_argument("--dbc", required=True, metavar="FILE.dbc", help="the CAN database that decodes its frames")
    p.add_argument(
        "--channel",
        metavar="CH",
        help="import only the frames of this channel of a log of several buses, as the log names it: candump's "
        "interface (can0), Vector's channel from 1 (BLF, ASC), PEAK's bus (TRC), MF4's bus channel",
    )
    p.add_argument(
        "--topic",
        metavar="TOPIC",
        help="a ROS 2 bag: import only the frames of this topic (/from_can_bus, ...), as the bag names it",
    )
    p.add_argument(
        "--timezone",
        metavar="ZONE",
        help="the time zone an ASC, TRC or BLF log was recorded in (an IANA name: Europe/Berlin; or UTC), for "
        "times in UTC (default: its local times logged as they read, the zone said to be unknown)",
    )
    p.add_argument(
        "--out",
        "-o",
        metavar="FILE.mcap",
        help="the MCAP log to write (default: LOG with .mcap; a bag's own .mcap file: .cosim.mcap)",
    )
    common.force_option(p)
    common.quiet_option(p)


def main(args: argparse.Namespace) -> int:
    from cosim.bus.bag_frames import is_bag
    from cosim.bus.log_clock import date_text
    from cosim.log.can_import import import_log

    log = Path(args.log)
    bag = is_bag(log)
    if args.topic is not None and not bag:
        raise CosimError(f"--topic picks a topic of a ROS 2 bag; {log} is a CAN log, whose buses --channel picks")
    if args.channel is not None and bag:
        raise CosimError(f"--channel: the buses of a ROS 2 bag are its topics; pick one with --topic ({log})")
    out = common.unused(Path(args.out) if args.out else default_output(log), args.force)
    result = import_log(log, args.dbc, out, args.topic if bag else args.channel, args.timezone)
    talk = common.console(stderr=True, quiet=args.quiet)
    common.warn(talk, result.warnings)
    record = result.record
    span = ((record.end_time_ns or 0) - (record.start_time_ns or 0)) / 1e9
    kind = "topic" if bag else "channel"
    channel = f" of {kind} {escape(record.channel)}" if record.channel else ""
    others = f"; {record.other_channels} frames of its other {kind}s left out" if record.channel else ""
    when = date_text(record.start_time_ns or 0, record.time_zone) or "no date recorded"
    talk.print(
        f"imported {record.frames} frames{channel} ({span:g} s of {record.format} from {when}): {record.decoded} "
        f"decoded into {len(result.topics)} messages by {escape(record.dbc)}{others}"
    )
    print(result.path)
    return 0


def default_output(log: Path) -> Path:
    """LOG with .mcap: a bag folder's name with .mcap beside it, a bag's own .mcap file with .cosim.mcap."""
    if log.is_dir():
        return log.parent / f"{log.resolve().name}.mcap"
    return log.with_suffix(".cosim.mcap" if log.suffix.lower() == ".mcap" else ".mcap")
