"""Draw a log's figures (PNG, SVG or PDF), for a screen or a paper.

Draw the figures of a run log: the state against every estimate, estimation errors per estimator,
the injected faults, and what the estimators publish (pseudoinverse weights s, z or Γ, the fault's
effect |h_Γ|, |Γ|, bias estimates φ̂ against the true fault, residuals, gain estimates, COFD
residuals, the trajectory of a closed loop). Axes carry units; text is in the figure (nothing
clipped); legends sit outside the data and name estimators, sensors and faults as the scenario
does. Every series has its colour (colour-blind safe), dash pattern and marker, so that seven stay
apart, also in grey print.

A bus log 'cosim import' wrote gets a figure per DBC message instead: its signals against the
time since the first frame (the axis names the date and its zone, or says it is unknown), a panel
per unit, at most 6 panels a page (a message of many signals gets pages MSG-1.png, MSG-2.png, ...);
messages without signals get none (a warning names them).

--style paper draws for a two-column paper: a column wide (3.5 in; --width double: 7.16 in, or
--width INCHES), 8 pt text, fonts embedded in PDFs (TrueType); with --no-title and --format pdf the
figures go into a paper as they are.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cosim.cli import common

EPILOG = """\
examples:
  cosim plot latest
  cosim plot run.mcap --style paper --format pdf --no-title --out figs
  cosim plot run.mcap --style paper --width double --estimators lft_test,lpv_test,raw"""


def width(text: str) -> str | float:
    """--width: single, double, or inches."""
    if text in ("single", "double"):
        return text
    try:
        inches = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give single, double or a width in inches") from None
    if not 1.0 <= inches <= 20.0:
        raise argparse.ArgumentTypeError(f"{inches:g}: give a width of 1 to 20 inches")
    return inches


def names(text: str) -> list[str]:
    """--estimators: names separated by commas."""
    found = [name.strip() for name in text.split(",") if name.strip()]
    if not found:
        raise argparse.ArgumentTypeError("give the estimators' names, separated by commas (lft,lpv)")
    return found


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", metavar="FILE.mcap", help=common.LOG_HELP)
    p.add_argument("--out", "-o", metavar="DIR", help="output directory (default: FILE-plots next to the log)")
    p.add_argument(
        "--format",
        choices=("png", "svg", "pdf"),
        default="png",
        help="png (default; raster at --dpi), svg or pdf (vector, text as text: for papers)",
    )
    p.add_argument(
        "--dpi", type=common.dpi, metavar="N", help="dots per inch of PNG figures (default 150; 300 with --style paper)"
    )
    p.add_argument(
        "--style",
        choices=("screen", "paper"),
        default="screen",
        help="screen (default: 9 in wide, titled) or paper (a column wide, 8 pt text, names as the scenario gives)",
    )
    p.add_argument(
        "--width",
        type=width,
        metavar="W",
        help="single (3.5 in, IEEE's column), double (7.16 in, both columns) or inches (default: single with "
        "--style paper, 9 in on screen)",
    )
    p.add_argument("--no-title", action="store_true", help="no title above the figures (a paper's caption says it)")
    p.add_argument(
        "--estimators",
        type=names,
        metavar="A,B",
        help="draw these estimators only, in this order (their looks follow it; default: all, as the log has them)",
    )


def main(args: argparse.Namespace) -> int:
    from cosim.analysis.plot import plot

    log = Path(common.latest_log(args.log))
    out = Path(args.out) if args.out else log.with_name(log.stem + "-plots")
    dpi = args.dpi or (300 if args.style == "paper" else 150)
    warnings: list[str] = []
    with common.preparing(common.console(stderr=True)):
        written = plot(
            log,
            out,
            fmt=args.format,
            dpi=dpi,
            warnings=warnings,
            style=args.style,
            width=args.width,
            title=not args.no_title,
            estimators=args.estimators,
        )
    for path in written:
        print(path)
    common.warn(common.error_console(), warnings)
    return 0
