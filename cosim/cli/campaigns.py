"""List the built-in campaigns.

List the built-in campaigns.
"""

from __future__ import annotations

import argparse

from rich.markup import escape
from rich.table import Table

from cosim.cli import common
from cosim.errors import CosimError


def main(args: argparse.Namespace) -> int:
    from cosim.campaign.spec import builtin_names, load_campaign

    table = Table(box=None, pad_edge=False, show_header=True, header_style="bold")
    for column in ("name", "runs", "description"):
        table.add_column(column)
    for name in builtin_names():
        try:
            campaign = load_campaign(name)
            table.add_row(name, str(campaign.size), campaign.spec.description)
        except CosimError as error:
            table.add_row(name, "-", f"[red]invalid: {escape(str(error))}[/red]")
    common.console().print(table)
    return 0
