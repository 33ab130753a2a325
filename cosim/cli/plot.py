"""Draw a log's figures (PNG, SVG or PDF).

Draw the figures of a run log: the state against every estimate, estimation errors per estimator,
the injected faults, and what the estimators publish (pseudoinverse weights s, z or Γ, the fault's
effect |h_Γ|, |Γ|, bias estimates φ̂ against the true fault, residuals, gain estimates, COFD
residuals, the trajectory of a closed loop). Axes carry units; text is in the figure (nothing
clipped).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cosim.cli import common


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
        "--dpi", type=common.dpi, default=150, metavar="N", help="dots per inch of PNG figures (default 150)"
    )


def main(args: argparse.Namespace) -> int:
    from cosim.analysis.plot import plot

    log = Path(common.latest_log(args.log))
    out = Path(args.out) if args.out else log.with_name(log.stem + "-plots")
    warnings: list[str] = []
    for path in plot(log, out, fmt=args.format, dpi=args.dpi, warnings=warnings):
        print(path)
    common.warn(common.error_console(), warnings)
    return 0
