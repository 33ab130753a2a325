"""List the estimators, controllers, fault models and plants a scenario can name.

List every kind a scenario can name (estimators' and the controller's 'kind', faults' 'kind', the
plant's 'model'), with where it comes from: built into cosim, or an installed package's entry point
(groups cosim.estimators, cosim.controllers, cosim.faults, cosim.plants). A scenario can also name a
class in a file, 'observers.py:MyObserver' (docs/extending.md).
"""

from __future__ import annotations

import argparse

from rich.table import Table

from cosim.cli import common


def arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print a JSON object: group → [{name, source, target}]")


def main(args: argparse.Namespace) -> int:
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
