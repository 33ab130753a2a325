"""Export a scenario's plant with its faults as an FMU.

Package the scenario's plant with its sensor and actuator faults, noise and disturbances (seeded) as
an FMI 3.0 co-simulation FMU (docs/fmi.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cosim.cli import common


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="SCENARIO", help=common.SCENARIO_HELP)
    p.add_argument("--out", "-o", required=True, metavar="FILE.fmu", help="the FMU to write")
    common.force_option(p)
    p.add_argument("--seed", type=common.seed, metavar="N", help="the seed of its noise, faults and disturbances")
    common.set_option(p)


def main(args: argparse.Namespace) -> int:
    from cosim.run.fmu_export import export

    out = common.unused(Path(args.out), args.force)
    loaded = common.load_scenario(args.scenario, args.set, args.seed)
    common.error_console().print(f"wrote {export(loaded, out)}")
    return 0
