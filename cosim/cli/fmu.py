"""Export a scenario's plant with its faults, or one of its estimators, as an FMU.

Package the scenario's plant with its sensor and actuator faults, noise and disturbances (seeded),
or with --estimator NAME that estimator as its node runs it on the bus (inputs: the readings and
commands it reads, outputs: its estimate and diagnostics, parameters: its Params; the design
computed now and frozen in), as an FMI 3.0 co-simulation FMU (docs/fmi.md). With --inputs-from
LOG, also the table of what that estimator's node read in a logged run of the scenario: fed to the
FMU, it reproduces the node's logged estimates.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cosim.cli import common
from cosim.errors import CosimError


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="SCENARIO", help=common.SCENARIO_HELP)
    p.add_argument("--out", "-o", required=True, metavar="FILE.fmu", help="the FMU to write")
    p.add_argument(
        "--estimator", metavar="NAME", help="export this estimator of the scenario (default: the plant with its faults)"
    )
    p.add_argument(
        "--inputs-from",
        metavar="LOG.mcap",
        help="with --estimator: also write FILE.csv, what the estimator's node read on the bus in that run "
        "(the FMU's input table)",
    )
    common.force_option(p)
    p.add_argument(
        "--seed", type=common.seed, metavar="N", help="the seed of its noise, faults and disturbances (the plant's FMU)"
    )
    common.set_option(p)


def main(args: argparse.Namespace) -> int:
    out = common.unused(Path(args.out), args.force)
    if args.inputs_from is not None and args.estimator is None:
        raise CosimError("--inputs-from needs --estimator NAME: the inputs are those of an estimator's node")
    table = common.unused(out.with_suffix(".csv"), args.force) if args.inputs_from is not None else None
    loaded = common.load_scenario(args.scenario, args.set, args.seed)
    if args.estimator is not None:
        from cosim.run import fmu_estimator

        written = [fmu_estimator.export(loaded, args.estimator, out)]
        if table is not None:
            written.append(fmu_estimator.write_bus_inputs(Path(args.inputs_from), args.estimator, table))
    else:
        from cosim.run import fmu_export

        written = [fmu_export.export(loaded, out)]
    for path in written:
        common.error_console().print(f"wrote {path}")
    return 0
