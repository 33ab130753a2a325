"""The ``cosim`` command line: one module per command, ``common`` for what they share.

A command's module says what the command is for in its docstring (the first line, then the
description ``cosim COMMAND --help`` shows), gives examples in ``EPILOG`` where they help, declares
its options (``arguments(parser)``, if it has any) and does it (``main(args) -> int``, the exit
status). ``COMMANDS`` lists them in the order ``cosim --help`` does.
"""

from __future__ import annotations

import argparse
import sys

from rich.markup import escape

from cosim import __version__
from cosim.cli import (
    benchmark,
    campaign,
    campaigns,
    common,
    dataset,
    dbc,
    export,
    fmu,
    import_log,
    inspect,
    kinds,
    layout,
    leaderboard,
    monitor,
    node,
    plot,
    recover,
    replay,
    report,
    run,
    scenarios,
)
from cosim.errors import CosimError

EXAMPLES = """\
examples:
  cosim run                          run the default scenario (masses-bias)
  cosim run masses-bias --seed 3     a built-in scenario with another seed
  cosim run my.toml --out my.mcap    a scenario file of your own
  cosim run vessel-nominal --mode realtime --foxglove   watch it in Foxglove (ws://127.0.0.1:8765)
  cosim run --json -q                a machine-readable summary of the run on standard output
  cosim run masses-bias --set duration=5 --set 'faults[0].value=[0.5, 0, 0]'
  cosim scenarios [--json]           list the built-in scenarios
  cosim kinds                        the estimators, controllers, faults and plants a scenario can name
  cosim inspect latest               summarize the newest log in runs/
  cosim campaign masses-bias-sweep --out runs/sweep   many runs on a local Dask cluster
  cosim leaderboard runs/sweep/results.parquet --html board.html
  cosim dataset dataset-attacks --out runs/ds   a labelled data set of frames, signals, truth, split by seed
  cosim inspect runs/my.mcap --json  summarize a log for other tools
  cosim dbc --out bus.dbc            the CAN database, for candump/cantools/SavvyCAN
  cosim fmu masses-bias --out plant.fmu   the scenario's plant with its faults as an FMU
  cosim export runs/my.mcap --to mf4  the bus as an ASAM MDF4 log (also csv, parquet, blf, asc, trc, candump)
  cosim import drive.blf --dbc car.dbc --out drive.mcap   a vehicle's CAN log, decoded, for Foxglove
  cosim layout runs/my.mcap --out my-layout.json   a Foxglove layout for the log (or for a scenario)
  cosim plot runs/my.mcap --format pdf   the figures, for a paper (png, svg or pdf)
  cosim replay runs/my.mcap -e kalman  feed the log's bus traffic to one of its estimators again
  cosim report runs/my.mcap          one self-contained HTML page: scenario, metrics, figures
  cosim monitor                      watch the running co-simulation's signals live
  cosim replay runs/my.mcap --foxglove   play a log into Foxglove at its pace
"""

#: Every command, in the order ``cosim --help`` lists them.
COMMANDS = (
    run,
    node,
    monitor,
    scenarios,
    kinds,
    dbc,
    fmu,
    import_log,
    inspect,
    plot,
    report,
    export,
    layout,
    recover,
    replay,
    campaign,
    campaigns,
    benchmark,
    leaderboard,
    dataset,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cosim",
        description="Co-simulation testbed for fault-tolerant state estimation: a MuJoCo plant, injected "
        "faults, sensor readings and estimates as CAN frames, everything logged to MCAP.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"cosim {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        common.command(sub, command)
    return parser


def _feature(args: argparse.Namespace) -> str:
    """The command as the user gave it, for messages: ``cosim export --to mf4``."""
    feature = f"cosim {args.command}"
    if getattr(args, "to", None):
        feature += f" --to {args.to}"
    if getattr(args, "foxglove", None) is not None:
        feature += " --foxglove"
    return feature


def _import_can_without_mf4() -> None:
    """Import python-can without its MF4 support. Its first import loads asammdf with pandas where
    the export extra is installed (half a second of every command, and of every node's start-up),
    yet no command reads or writes MF4 through python-can; kept out of that import, python-can
    leaves MF4 out (as where asammdf is not installed), and asammdf itself stays importable
    afterwards (cosim's MF4 export uses it directly)."""
    if "can" in sys.modules or "asammdf" in sys.modules:
        return
    sys.modules["asammdf"] = None  # type: ignore[assignment]
    try:
        import can  # noqa: F401
    finally:
        if sys.modules.get("asammdf", False) is None:
            del sys.modules["asammdf"]


def main(argv: list[str] | None = None) -> int:
    _import_can_without_mf4()
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except CosimError as error:
        common.error_console().print(f"[red]error:[/red] {escape(str(error))}")
        return 1
    except ImportError as error:  # a package of an optional extra that is not installed
        from cosim.extras import missing_extra

        missing = missing_extra(error, _feature(args))
        if missing is None:
            raise
        common.error_console().print(f"[red]error:[/red] {escape(str(missing))}")
        return 1
    except OSError as error:  # the log or DBC cannot be written, a path is a directory, ...
        common.error_console().print(f"[red]error:[/red] {escape(str(error))}")
        return 1
    except KeyboardInterrupt as interrupt:
        if getattr(interrupt, "detail", ""):  # what was under way (an FMU that did not answer)
            common.error_console().print(f"[yellow]interrupted:[/yellow] {escape(interrupt.detail)}")  # type: ignore[attr-defined]
        return common.exit_code(interrupt)
