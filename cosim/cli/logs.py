"""The commands that read a run log: ``inspect``, ``plot``, ``report``, ``export``, ``layout``, ``recover``."""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.markup import escape

from cosim.cli import common

LOG_HELP = "a run log, or 'latest': the newest runs/*.mcap"

EXPORT_DESCRIPTION = """\
Export a run log for the tools engineers already use. The log is streamed: any length fits in memory.

tables, one row per tick, columns tick, 't [s]' (simulated time), then '<topic>.<field> [unit]' for the
truth and the decoded bus signals (state.x1 [m], faults.measured.x2 [m], EST_kalman.xhat_v1 [m/s], ...):
  csv       text; floats as the shortest decimal that reads back exactly
  parquet   columnar, units and source topic in each field's metadata
raw CAN frames, every frame on the bus, timestamped with simulated time:
  blf       Vector binary log (CANalyzer, CANoe, python-can)
  asc       Vector ASCII log (CANalyzer, CANoe, SavvyCAN, python-can)
  trc       PEAK trace, version 2.1 (PCAN-View, PCAN-Explorer; classic CAN only)
  mf4       ASAM MDF4 bus log, CAN_DataFrame layout, the DBC attached (asammdf, CANalyzer)
  candump   text log of 'candump -L': (t) can0 ID#DATA, ID##<flags>DATA for CAN FD (can-utils,
            SavvyCAN, cantools, python-can)

Decode frames with the DBC from 'cosim dbc SCENARIO' (the MF4 file carries it)."""


def register(sub) -> None:
    p = common.command(
        sub,
        "inspect",
        cmd_inspect,
        help="summarize a log",
        description="Summarize a run log: channels and message counts, duration, scenario, frame counts, and per "
        "estimator the RMS of |x - x̂| before and after the first fault, with units.",
    )
    p.add_argument("log", nargs="?", metavar="FILE.mcap", help=LOG_HELP + " (default)")
    p.add_argument("--json", action="store_true", help="print one JSON object (stable keys, for other tools)")

    p = common.command(
        sub,
        "plot",
        cmd_plot,
        help="draw a log's figures (PNG, SVG or PDF)",
        description="Draw the figures of a run log: the state against every estimate, estimation errors per "
        "estimator, the injected faults, and what the estimators publish (pseudoinverse weights s, z or Γ, the "
        "fault's effect |h_Γ|, |Γ|, bias estimates φ̂ against the true fault, residuals, gain estimates, COFD "
        "residuals, the trajectory of a closed loop). Axes carry units; text is in the figure (nothing clipped).",
    )
    p.add_argument("log", metavar="FILE.mcap", help=LOG_HELP)
    p.add_argument("--out", "-o", metavar="DIR", help="output directory (default: FILE-plots next to the log)")
    p.add_argument(
        "--format",
        choices=("png", "svg", "pdf"),
        default="png",
        help="png (default; raster at --dpi), svg or pdf (vector, text as text: for papers)",
    )
    p.add_argument(
        "--dpi", type=common.dpi, default=150, metavar="N", help="dots per inch of PNG figures (default 150)"
    )

    p = common.command(
        sub,
        "report",
        cmd_report,
        help="write a self-contained HTML report of a log",
        description="Write one HTML page about a run log: the scenario and its settings, the metrics "
        "of 'cosim inspect' as tables, and the figures of 'cosim plot'. The page is self-contained "
        "(figures inlined, no network needed) and reads on a laptop and on a phone.",
    )
    p.add_argument("log", metavar="FILE.mcap", help=LOG_HELP)
    p.add_argument("--out", "-o", metavar="REPORT.html", help="output file (default: FILE.html next to the log)")

    _register_export(sub)
    _register_layout(sub)

    p = common.command(
        sub,
        "recover",
        cmd_recover,
        help="rebuild a log whose writer died (summary, indexes)",
        description="Rebuild the summary and indexes of a log whose writer died (a runner killed with SIGKILL, a "
        "full disk): its records are read in order, CRCs checked, up to the first damaged one, and written into a "
        "complete MCAP file that every reader opens (mcap's make_reader, @mcap/core, Foxglove). A record "
        "'cosim.recovered' says what was found. Without --out the log is replaced, once the new file is complete.",
    )
    p.add_argument("log", metavar="FILE.mcap")
    p.add_argument("--out", "-o", metavar="FIXED.mcap", help="write the recovered log here instead of replacing FILE")
    common.force_option(p)


#: ``cosim.analysis.export.FORMATS``, without importing the export at every start of the command line
#: (tests/test_export.py checks that they agree).
EXPORT_FORMATS = ("csv", "parquet", "blf", "asc", "trc", "mf4", "candump")


def _register_export(sub) -> None:
    p = common.command(
        sub,
        "export",
        cmd_export,
        help="export a log for other tools (CSV, Parquet, BLF, ASC, TRC, MF4, candump)",
        description=EXPORT_DESCRIPTION,
        epilog="examples:\n  cosim export runs/my.mcap --to csv\n  cosim export runs/my.mcap --to mf4 --out bus.mf4\n"
        "  cosim export latest --to asc",
    )
    p.add_argument("log", metavar="FILE.mcap", help=LOG_HELP)
    p.add_argument("--to", required=True, choices=EXPORT_FORMATS, help="output format")
    p.add_argument(
        "--out",
        "-o",
        metavar="PATH",
        help="output file (default: FILE.csv, .parquet, .blf, .asc, .trc, .mf4 or .log next to the log)",
    )
    common.force_option(p)
    p.add_argument(
        "--dbc", metavar="FILE.dbc", help="mf4 only: the DBC to attach, for a log that has none (default: the log's)"
    )
    p.add_argument(
        "--start-time",
        metavar="WHEN",
        help="frame logs: the wall-clock time of tick 0, an ISO 8601 date and time (2025-06-01T12:00:00Z; UTC "
        "without a zone) or seconds since the Unix epoch; 0: the epoch (t = 0 s) (default: when the run started, "
        "to the millisecond)",
    )


def _register_layout(sub) -> None:
    p = common.command(
        sub,
        "layout",
        cmd_layout,
        help="write a Foxglove layout for a log or a scenario",
        description="Write a Foxglove layout for a run: estimates against the truth per state, estimation errors "
        "(a user\nscript), the injected faults, diagnosis flags and residuals, and the trajectory of a planar "
        "plant. Every message\npath is a topic and field of the run's log. Open the log in Foxglove, then Layouts → "
        "Import from file.",
        epilog="examples:\n  cosim layout runs/my.mcap --out my-layout.json\n"
        "  cosim layout masses-faults-fd --out fd-layout.json   (for the scenario's logs and its live runs)",
    )
    p.add_argument(
        "target",
        nargs="?",
        metavar="LOG|SCENARIO",
        help="a run log (FILE.mcap), or a built-in scenario or TOML file (default: masses-bias)",
    )
    p.add_argument(
        "--out",
        "-o",
        metavar="FILE.json",
        help="output file (default: FILE.layout.json next to the log, or <scenario>.layout.json)",
    )


def cmd_inspect(args: argparse.Namespace) -> int:
    from cosim.analysis.summary import render, summarize

    report = summarize(common.latest_log(args.log))
    if args.json:
        common.print_json(report)
    else:
        render(report, common.console(wide=True))
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from cosim.analysis.plot import plot

    log = Path(common.latest_log(args.log))
    out = Path(args.out) if args.out else log.with_name(log.stem + "-plots")
    for path in plot(log, out, fmt=args.format, dpi=args.dpi):
        print(path)
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from cosim.analysis.report import report

    log = Path(common.latest_log(args.log))
    print(report(log, Path(args.out) if args.out else log.with_suffix(".html")))
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from datetime import UTC, datetime

    from cosim.analysis.export import FRAME_FORMATS, default_output, export, parse_start_time

    log = common.latest_log(args.log)
    out = common.unused(Path(args.out) if args.out else default_output(log, args.to), args.force)
    start = None if args.start_time is None else parse_start_time(args.start_time)
    result = export(log, args.to, out, dbc=args.dbc, start_ns=start)
    talk = common.error_console()
    common.warn(talk, result.warnings)
    what = "rows (ticks)" if args.to in ("csv", "parquet") else "frames"
    stamped = ""
    if args.to in FRAME_FORMATS and result.start_ns is not None:
        when = datetime.fromtimestamp(result.start_ns / 1e9, UTC)
        stamped = f", tick 0 at {when.isoformat(timespec='milliseconds').replace('+00:00', 'Z')}"
    talk.print(f"wrote {result.count} {what} as {args.to}{stamped}")
    print(result.path)
    return 0


def cmd_layout(args: argparse.Namespace) -> int:
    from cosim.analysis import layout

    target = args.target
    if target is not None and target.endswith(".mcap"):
        signals = layout.signals_of_log(target)
    else:
        from cosim.run.plan import RunPlan

        plan = RunPlan.build(common.load_scenario(target, None))
        units = {name: unit for table in plan.units.values() for name, unit in table.items()}
        signals = layout.RunSignals.of(plan.run_record(), plan.codec, units)
    default = Path(target).with_suffix(".layout.json") if target and target.endswith(".mcap") else None
    out = Path(args.out) if args.out else default or Path(f"{signals.scenario}.layout.json")
    written = layout.write(layout.build(signals), out)
    common.error_console().print(
        f"wrote the Foxglove layout of {escape(signals.scenario)}: Foxglove → Layouts → Import from file"
    )
    print(written)
    return 0


def cmd_recover(args: argparse.Namespace) -> int:
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
