"""The commands about scenarios and what they are made of: ``scenarios``, ``kinds``, ``dbc``, ``fmu``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from rich.markup import escape
from rich.table import Table

from cosim.cli import common
from cosim.errors import CosimError


def register(sub) -> None:
    p = common.command(
        sub, "scenarios", cmd_scenarios, help="list the built-in scenarios", description="List the built-in scenarios."
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="print a JSON list: name, default, description, plant, duration_s, sample_time_s, estimators, bus, "
        "error (null unless the file is invalid)",
    )

    p = common.command(
        sub,
        "kinds",
        cmd_kinds,
        help="list the estimators, controllers, fault models and plants a scenario can name",
        description="List every kind a scenario can name (estimators' and the controller's 'kind', faults' "
        "'kind', the plant's 'model'), with where it comes from: built into cosim, or an installed package's "
        "entry point (groups cosim.estimators, cosim.controllers, cosim.faults, cosim.plants). A scenario "
        "can also name a class in a file, 'observers.py:MyObserver' (docs/extending.md).",
    )
    p.add_argument("--json", action="store_true", help="print a JSON object: group → [{name, source, target}]")

    p = common.command(
        sub,
        "dbc",
        cmd_dbc,
        help="write the CAN database of a scenario",
        description="Write the DBC database of a scenario's bus, so that external tools can decode its frames.",
    )
    p.add_argument(
        "scenario", nargs="?", metavar="SCENARIO", help="built-in scenario name or TOML path (default: masses-bias)"
    )
    p.add_argument("--out", "-o", metavar="FILE.dbc", help="output file (default: standard output)")
    common.set_option(p)

    p = common.command(
        sub,
        "fmu",
        cmd_fmu,
        help="export a scenario's plant with its faults as an FMU",
        description="Package the scenario's plant with its sensor and actuator faults, noise and disturbances "
        "(seeded) as an FMI 3.0 co-simulation FMU (docs/fmi.md).",
    )
    p.add_argument("scenario", metavar="SCENARIO", help="built-in scenario name or TOML path")
    p.add_argument("--out", "-o", required=True, metavar="FILE.fmu", help="the FMU to write")
    common.force_option(p)
    p.add_argument("--seed", type=common.seed, metavar="N", help="the seed of its noise, faults and disturbances")
    common.set_option(p)


def cmd_scenarios(args: argparse.Namespace) -> int:
    from cosim import scenario

    listing = [_describe(name, name == scenario.DEFAULT_SCENARIO) for name in scenario.builtin_names()]
    if args.json:
        common.print_json(listing)
        return 0
    table = Table(box=None, pad_edge=False, show_header=True, header_style="bold")
    table.add_column("name")
    table.add_column("description")
    for entry in listing:
        marker = " (default)" if entry["default"] else ""
        description = (
            entry["description"] if entry["error"] is None else f"[red]invalid: {escape(entry['error'])}[/red]"
        )
        table.add_row(entry["name"] + marker, description)
    common.console().print(table)
    return 0


def _describe(name: str, default: bool) -> dict[str, Any]:
    """A built-in scenario as ``cosim scenarios --json`` lists it."""
    from cosim import scenario

    try:
        s = scenario.load(name).scenario
    except CosimError as error:
        return {"name": name, "default": default, "error": str(error)}
    return {
        "name": name,
        "default": default,
        "description": s.description,
        "plant": s.plant.model,
        "duration_s": s.duration,
        "sample_time_s": s.sample_time,
        "estimators": [e.name for e in s.estimators],
        "bus": "CAN FD" if s.bus.fd else "classic CAN",
        "error": None,
    }


def kinds() -> dict[str, list[dict[str, str]]]:
    """Every kind of every group, with its origin (nothing is imported but the tables)."""
    from estimators import ESTIMATORS
    from estimators.controller import CONTROLLERS
    from faults.models import FAULT_MODELS
    from mjcf import PLANTS

    listing: dict[str, list[dict[str, str]]] = {}
    for group in (ESTIMATORS, CONTROLLERS, FAULT_MODELS, PLANTS):
        entries = []
        for name in group:
            origin = group.origin(name)
            entries.append(
                {"name": name, "source": origin.source, "target": origin.target}
                | ({"distribution": origin.distribution} if origin.distribution else {})
            )
        listing[group.group] = entries
    return listing


def cmd_kinds(args: argparse.Namespace) -> int:
    listing = kinds()
    if args.json:
        common.print_json(listing)
        return 0
    talk = common.console()
    for group, entries in listing.items():
        table = Table(title=group, title_justify="left", box=None, header_style="bold", pad_edge=False)
        for column in ("name", "from", "module:class"):
            table.add_column(column)
        for entry in entries:
            source = entry["source"] if "distribution" not in entry else f"{entry['distribution']} (entry point)"
            table.add_row(entry["name"], source, entry["target"])
        talk.print(table)
        talk.print()
    talk.print('[dim]a scenario also takes a class in a file: kind = "observers.py:MyObserver"[/dim]')
    return 0


def cmd_dbc(args: argparse.Namespace) -> int:
    text = common.load_scenario(args.scenario, args.set).scenario.codec().dbc
    if args.out:
        Path(args.out).write_text(text)
        common.error_console().print(f"wrote {args.out}")
    else:
        sys.stdout.write(text)
    return 0


def cmd_fmu(args: argparse.Namespace) -> int:
    from cosim.run.fmu_export import export

    out = common.unused(Path(args.out), args.force)
    loaded = common.load_scenario(args.scenario, args.set, args.seed)
    common.error_console().print(f"wrote {export(loaded, out)}")
    return 0
