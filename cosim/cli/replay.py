"""Feed a log's bus traffic to an estimator, or play it onto a live bus.

Replay a run log without simulating the plant again.

With --estimator: the frames the runner put on the bus (SYNC, sensor and command frames, tick by
tick, as the bus delivered them: frames a dropout kept off the bus stay off) go to one estimator, a
'cosim node' process on a bus of its own, in lockstep. The new log holds the original truth, those
frames, the estimator's answers, and 'cosim.replay' metadata. An estimator of the run, unchanged,
reproduces its logged frames bit for bit (its design is taken from the log); --param changes its
parameters (and designs it again); --kind makes a new one, designed on the linear model the log
records.

With --live: every frame of the log goes onto a bus at its recorded pace over --speed, like
canplayer, for external tools and clients (decode with 'cosim dbc'); the log may be any CAN log
python-can reads too (candump -L .log, BLF, ASC, TRC, MF4), or one 'cosim import' wrote.

With --foxglove: every message of the log (every topic) goes to Foxglove over its WebSocket
protocol, at its simulated time over --speed, stamped at the run's start plus simulated time.

Exit status: 0 when the replay completed; 4 when it completed but the estimator failed during it
(its step raised: the new log says why); 1 on an error; 130 or 143 when interrupted.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING

from rich.console import Console
from rich.markup import escape

from cosim.cli import common
from cosim.errors import CosimError

if TYPE_CHECKING:
    from cosim.bus.transport import BusConfig

EPILOG = """\
examples:
  cosim replay runs/my.mcap --estimator kalman --out kalman-again.mcap
  cosim replay runs/my.mcap --estimator kalman --param measurement_std=0.01 --out kf-0.01.mcap
  cosim replay runs/my.mcap --estimator kalman --set estimators[1].params.measurement_std=0.01
  cosim replay runs/my.mcap --estimator kf2 --kind kalman --param 'x0=[0, 0, 0, 0]'
  cosim replay latest --estimator mine --kind observers.py:MyObserver
  cosim replay runs/my.mcap --live --speed 0.5
  cosim replay runs/my.mcap --live --interface socketcan --channel vcan0
  cosim replay drive.blf --live --interface socketcan --channel vcan0   (any CAN log, at its pace)
  cosim replay runs/my.mcap --foxglove --speed 2"""


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "log",
        metavar="FILE.mcap",
        help="a run log, or 'latest': the newest runs/*.mcap; with --live any CAN log (.log, .blf, .asc, .trc, .mf4)",
    )
    p.add_argument(
        "--estimator",
        "-e",
        metavar="NAME",
        help="the estimator to feed: one of the run's, or the name of a new one (with --kind)",
    )
    p.add_argument(
        "--kind",
        metavar="KIND",
        help="a new estimator of this kind (pseudoinverse, kalman, adaptive, uio, ..., a plugin's name, "
        "or file.py:ClassName; 'cosim kinds' lists them)",
    )
    p.add_argument(
        "--param",
        action="append",
        metavar="KEY=VALUE",
        help='an estimator parameter, VALUE in TOML syntax (0.5, [0.8, 0.9], "text"); repeat for several',
    )
    p.add_argument(
        "--out", "-o", metavar="NEW.mcap", help="where to write the replay's log (default: FILE-replay-NAME.mcap)"
    )
    common.set_option(
        p,
        "a setting of the run's scenario the replay can honour: the replayed estimator's "
        "estimators[i].params.NAME (the same as --param NAME); anything that changes what was sent needs 'cosim run'",
    )
    common.force_option(p)
    p.add_argument("--live", action="store_true", help="play every frame of the log onto a bus in real time instead")
    p.add_argument(
        "--speed",
        type=float,
        metavar="X",
        help="--live, --foxglove: simulated seconds per wall-clock second (default 1)",
    )
    common.bus_options(p, "udp_multicast")
    common.quiet_option(p)
    common.foxglove_options(
        p,
        "serve every message of the log over the Foxglove WebSocket protocol on PORT (default 8765; 0: a free one), "
        "at its simulated time over --speed (0: at once), once Foxglove has subscribed",
    )
    p.add_argument(
        "--wait",
        type=float,
        default=60.0,
        metavar="S",
        help="--foxglove: how long to wait for Foxglove to subscribe before playing (default 60 s)",
    )


def main(args: argparse.Namespace) -> int:
    args.log = common.latest_log(args.log)
    talk = common.console(stderr=True, quiet=args.quiet)
    if args.foxglove is not None:
        return _play_foxglove(args, talk)
    if args.live:
        return _play(args, talk)
    with common.preparing(talk) as preparation:
        return _replay(args, talk, preparation)


def _replay(args: argparse.Namespace, talk: Console, preparation: common.Preparation | None) -> int:
    """An estimator replayed on the log's frames into a new log."""
    from cosim.run.replay import Replay, parse_params
    from cosim.scenario import parse_setting

    common.refuse(
        args, ("--speed",), "only with --live (an estimator replay runs in lockstep, as fast as the node answers)"
    )
    if not args.estimator:
        raise CosimError("replay needs --estimator NAME (one of the run's, or a new one with --kind), or --live")
    log = Path(args.log)
    same = args.out is not None and log.exists() and Path(args.out).resolve() == log.resolve()  # Replay says why not
    default = log.with_name(f"{log.stem}-replay-{args.estimator}.mcap")
    out = Path(args.out) if same else common.new_output(args.out, default, args.force)
    replay = Replay(
        log,
        out,
        args.estimator,
        kind=args.kind,
        params=parse_params(args.param or []),
        settings=[parse_setting(text) for text in args.set or []],
        interface=args.interface,
        channel=args.channel,
        port=args.port,
    )
    origin = "new, " if replay.new else ""
    talk.print(
        f"replaying {replay.ticks} ticks of {escape(str(log))} into {escape(replay.name)} ({origin}{replay.kind})"
    )
    where = f"the replay up to that point is in {escape(str(out))}"
    try:
        result = common.with_progress(
            replay, talk, lambda run: talk.print(f"bus: {common.joining(run.bus)}"), preparation
        )
    except KeyboardInterrupt as interrupt:
        return common.interrupted(common.error_console(), interrupt, f"; {where}")
    except CosimError as error:
        common.error_console().print(f"[red]error:[/red] {escape(str(error))}\n{where}")
        return 1
    talk.print(
        f"done: {result.ticks} ticks, {result.frames} frames ({result.frames_lost} lost) in {result.wall_time:.2f} s"
    )
    common.say_failed(talk, result)
    print(out)
    return common.ESTIMATOR_FAILED if result.failed else 0


def _play_foxglove(args: argparse.Namespace, talk: Console) -> int:
    from cosim.log.live import log_start_ns, play

    common.refuse(
        args,
        ("--estimator", "--kind", "--param", "--set", "--out", "--live", "--interface", "--channel", "--port"),
        "not with --foxglove, which serves the log's messages to Foxglove as they are",
    )
    speed = 1.0 if args.speed is None else args.speed
    with common.foxglove_sink(args, "cosim replay --foxglove", log_start_ns(args.log)) as sink:
        talk.print(
            f"Foxglove: open connection {sink.url} (Foxglove WebSocket), or {sink.app_url()}; "
            f"waiting up to {args.wait:g} s for it to subscribe, then playing {escape(args.log)} at "
            + ("full speed" if speed == 0 else f"{speed:g}x real time")
        )

        def ready(viewer: bool) -> None:
            if not viewer:
                talk.print("[yellow]no Foxglove client subscribed; playing anyway[/yellow]")

        started = time.perf_counter()
        try:
            count, sim_time, warnings = play(args.log, sink, speed, wait=args.wait, on_ready=ready)
        except KeyboardInterrupt as interrupt:
            return common.interrupted(common.error_console(), interrupt)
    common.warn(talk, warnings)
    talk.print(f"served {count} messages ({sim_time:g} s of simulated time) in {time.perf_counter() - started:.2f} s")
    return 0


def _play(args: argparse.Namespace, talk: Console) -> int:
    from cosim.run.replay import play

    common.refuse(
        args,
        ("--estimator", "--kind", "--param", "--set", "--out"),
        "not with --live, which plays the log's frames onto a bus as they are",
    )
    speed = 1.0 if args.speed is None else args.speed

    def started(bus: BusConfig) -> None:
        talk.print(f"playing {escape(args.log)} at {speed:g}x real time onto {common.joining(bus)}")

    try:
        result = play(args.log, args.interface or "udp_multicast", args.channel or "", args.port or 0, speed, started)
    except KeyboardInterrupt as interrupt:
        return common.interrupted(common.error_console(), interrupt)
    common.warn(talk, result.warnings)
    talk.print(f"sent {result.frames} frames ({result.sim_time:g} s of the log's time) in {result.wall_time:.2f} s")
    return 0
