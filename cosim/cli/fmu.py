"""Export a scenario's plant with its faults, or one of its estimators, as an FMU.

Package the scenario's plant with its sensor and actuator faults, noise and disturbances (seeded),
or with --estimator NAME that estimator as its node runs it on the bus (inputs: the readings and
commands it reads, outputs: its estimate and diagnostics, parameters: its Params; the design
computed now and frozen in), as an FMI 3.0 co-simulation FMU (docs/fmi.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cosim.cli import common


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="SCENARIO", help=common.SCENARIO_HELP)
    p.add_argument("--out", "-o", required=True, metavar="FILE.fmu", help="the FMU to write")
    p.add_argument(
        "--estimator", metavar="NAME", help="export this estimator of the scenario (default: the plant with its faults)"
    )
    common.force_option(p)
    p.add_argument("--seed", type=common.seed, metavar="N", help="the seed of its noise, faults and disturbances")
    common.set_option(p)


def main(args: argparse.Namespace) -> int:
    out = common.unused(Path(args.out), args.force)
    loaded = common.load_scenario(args.scenario, args.set, args.seed)
    if args.estimator is not None:
        from cosim.run import fmu_estimator

        written = fmu_estimator.export(loaded, args.estimator, out)
    else:
        from cosim.run import fmu_export

        written = fmu_export.export(loaded, out)
    common.error_console().print(f"wrote {written}")
    return 0
