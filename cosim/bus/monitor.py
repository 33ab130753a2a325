"""``cosim monitor``: the decoded signals of a running co-simulation, or of any bus with a DBC, live."""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from cosim.bus import registry
from cosim.bus.client import Client
from cosim.bus.codec import Decoded
from cosim.bus.transport import BusConfig, drain, open_bus
from cosim.errors import CosimError


def _table(latest: dict[str, Decoded], header: str) -> Group:
    table = Table(box=None, header_style="bold", pad_edge=False)
    for column in ("message", "sender", "tick", "signals"):
        table.add_column(column, justify="right" if column == "tick" else "left")
    for name in sorted(latest, key=lambda n: latest[n].spec.frame_id):
        decoded = latest[name]
        units = {signal: channel.unit for channel, signal in zip(decoded.spec.channels, decoded.spec.signals)}
        table.add_row(name, decoded.spec.sender, str(decoded.tick), _values(decoded.values, units))
    return Group(Text(header), table)


def _values(values: Mapping[str, Any], units: Mapping[str, str | None]) -> str:
    """A message's signals in a line: name=value unit."""
    return "  ".join(
        f"{key}={value:.6g}{f' {units[key]}' if units.get(key) else ''}"
        if isinstance(value, float)
        else f"{key}={value}"
        for key, value in values.items()
    )


class _Count:
    """Frames seen (and not decodable) since the start, and whether the display is due (5 per second)."""

    def __init__(self) -> None:
        self.frames = self.unknown = 0
        self.started, self.shown = time.monotonic(), 0.0

    def due(self) -> bool:
        now = time.monotonic()
        if now - self.shown <= 0.2:
            return False
        self.shown = now
        return True

    def __str__(self) -> str:
        rate = self.frames / max(time.monotonic() - self.started, 1e-9)
        unknown = f" ({self.unknown} unknown)" if self.unknown else ""
        return f"{self.frames} frames{unknown}, {rate:,.0f} frames/s"


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
    count = _Count()
    with Client.attach(None, info["id"]) as client:
        try:
            with Live(_table(latest, header), console=console, refresh_per_second=5, transient=False) as live:
                for decoded in client.frames(timeout=None):
                    latest[decoded.spec.name] = decoded
                    count.frames += 1
                    if count.due():
                        live.update(_table(latest, f"{header}   {count}"))
                live.update(_table(latest, f"{header}   {count.frames} frames: the run has stopped"))
        except KeyboardInterrupt:
            pass
    return 0


def watch(dbc: str, interface: str, channel: str | None, port: int | None, console: Console) -> int:
    """Show the frames of any bus decoded with the DBC file ``dbc`` (any DBC: a bench's, or one from
    ``cosim dbc``) until Ctrl-C; frames the database does not know are counted."""
    import cantools

    if not channel:
        raise CosimError("--dbc: say which bus with --channel (a multicast group, a CAN interface such as vcan0)")
    if interface == "udp_multicast" and port is None:
        raise CosimError("--dbc on udp_multicast: say which port with --port (cosim run prints it)")
    try:
        database = cantools.database.load_file(dbc, database_format="dbc", strict=False)
    except (OSError, cantools.database.UnsupportedDatabaseFormatError, ValueError) as error:
        raise CosimError(f"--dbc {dbc}: cannot read it as a DBC database ({str(error).splitlines()[0]})") from None
    config = BusConfig(interface, channel, port, fd=True)
    header = f"{dbc} on {config.describe()}"
    if not isinstance(database, cantools.database.can.Database):
        raise CosimError(f"--dbc {dbc}: not a CAN database")
    latest: dict[str, tuple[Any, Any]] = {}
    count = _Count()
    bus = open_bus(config)
    try:
        with Live(_signals(latest, header), console=console, refresh_per_second=5, transient=False) as live:
            while True:
                for frame in drain(bus, 0.1):
                    count.frames += 1
                    try:
                        message = database.get_message_by_frame_id(frame.arbitration_id)
                        latest[message.name] = (message, message.decode(bytes(frame.data), decode_choices=False))
                    except (KeyError, ValueError, cantools.database.DecodeError):
                        count.unknown += 1
                if count.due():
                    live.update(_signals(latest, f"{header}   {count}"))
    except KeyboardInterrupt:
        pass
    finally:
        bus.shutdown()
    return 0


def _signals(latest: dict[str, tuple[Any, Any]], header: str) -> Group:
    table = Table(box=None, header_style="bold", pad_edge=False)
    for column in ("message", "id", "sender", "signals"):
        table.add_column(column)
    for name in sorted(latest, key=lambda n: latest[n][0].frame_id):
        message, values = latest[name]
        units = {signal.name: signal.unit for signal in message.signals}
        table.add_row(name, f"{message.frame_id:03X}", ", ".join(message.senders), _values(values, units))
    return Group(Text(header), table)
