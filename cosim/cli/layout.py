"""Write a Foxglove layout for a log or a scenario.

Write a Foxglove layout for a run: estimates against the truth per state, estimation errors (a user
script), the injected faults, diagnosis flags and residuals, and the trajectory of a planar plant.
Every message path is a topic and field of the run's log. Open the log in Foxglove, then Layouts →
Import from file. For a log of 'cosim import': a plot of each DBC message's signals, a tab per
sending node.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.markup import escape

from cosim.cli import common

EPILOG = (
    "examples:\n  cosim layout runs/my.mcap --out my-layout.json\n"
    "  cosim layout masses-faults-fd --out fd-layout.json   (for the scenario's logs and its live runs)"
)


def arguments(p: argparse.ArgumentParser) -> None:
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


def main(args: argparse.Namespace) -> int:
    from cosim.analysis import bus_layout, layout

    target = args.target
    if target is not None and target.endswith(".mcap") and bus_layout.is_imported(target):
        name, built = bus_layout.layout_of_log(target)  # a bus log of another tool: a plot per message
        written = layout.write(built, Path(args.out) if args.out else Path(target).with_suffix(".layout.json"))
        common.error_console().print(
            f"wrote the Foxglove layout of {escape(name)}: Foxglove → Layouts → Import from file"
        )
        print(written)
        return 0
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
