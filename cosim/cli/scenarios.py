"""List the built-in scenarios.

List the built-in scenarios.
"""

from __future__ import annotations

import argparse
from typing import Any

from rich.markup import escape
from rich.table import Table

from cosim.cli import common
from cosim.errors import CosimError


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--json",
        action="store_true",
        help="print a JSON list: name, default, description, plant, duration_s, sample_time_s, estimators, bus, "
        "error (null unless the file is invalid)",
    )


def main(args: argparse.Namespace) -> int:
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
