"""``cosim monitor``: the decoded signals of a running co-simulation, live."""

from __future__ import annotations

import time
from typing import Any

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from cosim.bus import registry
from cosim.bus.client import Client
from cosim.bus.codec import Decoded
from cosim.errors import CosimError


def _table(latest: dict[str, Decoded], header: str) -> Group:
    table = Table(box=None, header_style="bold", pad_edge=False)
    for column in ("message", "sender", "tick", "signals"):
        table.add_column(column, justify="right" if column == "tick" else "left")
    for name in sorted(latest, key=lambda n: latest[n].spec.frame_id):
        decoded = latest[name]
        units = {signal: channel.unit for channel, signal in zip(decoded.spec.channels, decoded.spec.signals)}
        signals = "  ".join(
            f"{key}={value:.6g}{(' ' + units[key]) if units.get(key) else ''}"
            if isinstance(value, float)
            else f"{key}={value}"
            for key, value in decoded.values.items()
        )
        table.add_row(name, decoded.spec.sender, str(decoded.tick), signals)
    return Group(Text(header), table)


def find_run(run: str | None, command: str) -> dict[str, Any]:
    """The running co-simulation ``run`` (an id or its start) names, or the only one; when several
    run and none is named, the error lists them and says how to choose: ``<command> --run ID``."""
    runs = registry.active()
    if run is None and len(runs) > 1:
        listing = "; ".join(
            f"{info['id']} ({info['scenario']}, {info['bus']['interface']} {info['bus']['channel']})" for info in runs
        )
        raise CosimError(
            f"{len(runs)} co-simulations are running: {listing}; choose one with --run ID "
            f"(e.g. {command} --run {runs[-1]['id']}; the start of an id is enough)"
        )
    return registry.find(run)


def monitor(run: str | None, console: Console) -> int:
    """Attach to the running co-simulation and show its frames until it stops (or Ctrl-C)."""
    info = find_run(run, "cosim monitor")
    header = f"{info['scenario']} (run {info['id']}) on {info['bus']['interface']} {info['bus']['channel']}"
    latest: dict[str, Decoded] = {}
    frames, started, shown = 0, time.monotonic(), 0.0
    with Client.attach(None, info["id"]) as client:
        try:
            with Live(_table(latest, header), console=console, refresh_per_second=5, transient=False) as live:
                for decoded in client.frames(timeout=None):
                    latest[decoded.spec.name] = decoded
                    frames += 1
                    now = time.monotonic()
                    if now - shown > 0.2:
                        shown = now
                        rate = frames / max(now - started, 1e-9)
                        live.update(_table(latest, f"{header}   {frames} frames, {rate:,.0f} frames/s"))
                live.update(_table(latest, f"{header}   {frames} frames: the run has stopped"))
        except KeyboardInterrupt:
            pass
    return 0
