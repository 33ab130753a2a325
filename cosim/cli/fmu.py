"""Export a scenario's plant with its faults, one of its estimators, or the whole scenario as a
system of FMUs.

Package the scenario's plant with its sensor and actuator faults, noise and disturbances (seeded),
or with --estimator NAME that estimator as its node runs it on the bus (inputs: the readings and
commands it reads, outputs: its estimate and diagnostics, parameters: its Params; the design
computed now and frozen in), as an FMI 3.0 co-simulation FMU, or FMI 2.0 with --fmi 2 (docs/fmi.md).
With --inputs-from LOG, also the table of what that estimator's node read in a logged run of the
scenario: fed to the FMU, it reproduces the node's logged estimates.

With --system, write to the folder --out the scenario as a system that another co-simulation engine
runs: the plant's FMU, one per estimator and the controller's in a closed loop, wired as the run's
frames carry the values, as an SSP archive (SCENARIO.ssp) and as the Open Simulation Platform's
OspSystemStructure.xml beside the FMUs (libcosim runs FMI 2.0 FMUs: use --fmi 2 for it).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cosim.cli import common
from cosim.errors import CosimError


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="SCENARIO", help=common.SCENARIO_HELP)
    p.add_argument(
        "--out", "-o", required=True, metavar="FILE.fmu", help="the FMU to write (with --system: the folder to write)"
    )
    p.add_argument(
        "--estimator", metavar="NAME", help="export this estimator of the scenario (default: the plant with its faults)"
    )
    p.add_argument(
        "--system",
        action="store_true",
        help="export the whole scenario as a system of FMUs (SSP archive and OspSystemStructure.xml) into --out",
    )
    p.add_argument(
        "--fmi", type=int, choices=(2, 3), default=3, help="the FMI version of the FMUs (default 3; libcosim runs 2)"
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
    if args.inputs_from is not None and args.estimator is None:
        raise CosimError("--inputs-from needs --estimator NAME: the inputs are those of an estimator's node")
    if args.system and args.estimator is not None:
        raise CosimError("--system exports every estimator of the scenario: leave out --estimator")
    if args.system:
        return _system(args)
    out = common.unused(Path(args.out), args.force)
    table = common.unused(out.with_suffix(".csv"), args.force) if args.inputs_from is not None else None
    loaded = common.load_scenario(args.scenario, args.set, args.seed)
    if args.estimator is not None:
        from cosim.run import fmu_estimator

        written = [fmu_estimator.export(loaded, args.estimator, out, args.fmi)]
        if table is not None:
            written.append(fmu_estimator.write_bus_inputs(Path(args.inputs_from), args.estimator, table))
    else:
        from cosim.run import fmu_export

        written = [fmu_export.export(loaded, out, args.fmi)]
    for path in written:
        common.error_console().print(f"wrote {path}")
    return 0


def _system(args: argparse.Namespace) -> int:
    from cosim.run import fmu_ssp

    folder = Path(args.out)
    if folder.exists() and not folder.is_dir():
        raise CosimError(f"--out {folder} is a file: with --system it is the folder to write the system into")
    loaded = common.load_scenario(args.scenario, args.set, args.seed)
    talk = common.error_console()
    for path in fmu_ssp.export(loaded, folder, args.fmi, args.force):
        talk.print(f"wrote {path}")
    if args.fmi == 3:
        talk.print("note: libcosim (the Open Simulation Platform) runs FMI 2.0 FMUs only: export with --fmi 2 for it")
    return 0
