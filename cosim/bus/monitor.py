"""``cosim monitor``: the decoded signals of a running co-simulation, or of any bus with a DBC, live."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from cosim.bus import registry
from cosim.bus.client import Client
from cosim.bus.codec import Decoded
from cosim.bus.foreign import FrameDecoder, read_dbc
from cosim.bus.transport import BusConfig, drain, open_bus
from cosim.errors import CosimError

if TYPE_CHECKING:
    import can


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


class _Lines:
    """A monitor's output where it is not a terminal (a pipe, a file): a line per decoded message on
    ``console``'s stream, written at once, and what is monitored (and, at the end, how many frames)
    on standard error. A reader that goes away (``| head``) ends the monitor."""

    def __init__(self, console: Console, header: str) -> None:
        self.stream, self.count = console.file, _Count()
        print(header, file=sys.stderr, flush=True)

    def line(self, text: str) -> bool:
        """Writes a line; False once the reader has gone."""
        try:
            self.stream.write(text + "\n")
            self.stream.flush()
        except BrokenPipeError:
            os.dup2(os.open(os.devnull, os.O_WRONLY), self.stream.fileno())  # nothing left for Python to flush
            return False
        return True

    def end(self, how: str = "") -> int:
        print(f"{self.count}{how}", file=sys.stderr, flush=True)
        return 0


def _decoded_line(decoded: Decoded) -> str:
    """A message as a line: its name, sender, tick and signals (the columns of the live table)."""
    spec = decoded.spec
    units = {signal: channel.unit for channel, signal in zip(spec.channels, spec.signals)}
    return f"{spec.name} {spec.sender} {decoded.tick} {_values(decoded.values, units)}"


def monitor(run: str | None, console: Console) -> int:
    """Attach to the running co-simulation and show its frames until it stops (or Ctrl-C): a live
    table on a terminal, else a line per decoded message."""
    info = find_run(run, "cosim monitor")
    header = f"{info['scenario']} (run {info['id']}) on {info['bus']['interface']} {info['bus']['channel']}"
    latest: dict[str, Decoded] = {}
    count = _Count()
    with Client.attach(None, info["id"]) as client:
        if not console.is_terminal:
            lines = _Lines(console, header)
            try:
                for decoded in client.frames(timeout=None):
                    lines.count.frames += 1
                    if not lines.line(_decoded_line(decoded)):
                        return 0
            except KeyboardInterrupt:
                return lines.end()
            return lines.end(": the run has stopped")
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
    """Show the frames of any bus decoded with the DBC file ``dbc`` (any DBC cantools reads: a
    vehicle's, a bench's, or one from ``cosim dbc``) until Ctrl-C; a frame is looked up by its id
    and its own extended flag (``cosim.bus.foreign``), and frames the database does not describe
    are counted."""
    if not channel:
        raise CosimError("--dbc: say which bus with --channel (a multicast group, a CAN interface such as vcan0)")
    if interface == "udp_multicast" and port is None:
        raise CosimError("--dbc on udp_multicast: say which port with --port (cosim run prints it)")
    decoder = FrameDecoder(read_dbc(dbc))
    config = BusConfig(interface, channel, port, fd=True)
    header = f"{dbc} on {config.describe()}"
    bus = open_bus(config)
    try:
        if not console.is_terminal:
            return _watch_lines(bus, decoder, _Lines(console, header))
        return _watch_table(bus, decoder, console, header)
    finally:
        bus.shutdown()


def _frame_id(message: Any) -> str:
    """A DBC message's id as a table shows it: eight hex digits for an extended id, three for a standard one."""
    return f"{message.frame_id:08X}" if message.is_extended_frame else f"{message.frame_id:03X}"


def _watch_lines(bus: can.BusABC, decoder: FrameDecoder, lines: _Lines) -> int:
    """A line per decoded frame: the time since the start (s), then the columns of the live table."""
    started = time.monotonic()
    try:
        while True:
            for frame in drain(bus, 0.1):
                lines.count.frames += 1
                if (found := decoder.decode(frame)) is None:
                    lines.count.unknown += 1
                    continue
                message, values = found
                units = {signal.name: signal.unit for signal in message.signals}
                senders = ",".join(message.senders) or "-"
                text = f"{time.monotonic() - started:.3f} {message.name} {_frame_id(message)} {senders} "
                if not lines.line(text + _values(values, units)):
                    return 0
    except KeyboardInterrupt:
        return lines.end()


def _watch_table(bus: can.BusABC, decoder: FrameDecoder, console: Console, header: str) -> int:
    latest: dict[str, tuple[Any, Any]] = {}
    count = _Count()
    try:
        with Live(_signals(latest, header), console=console, refresh_per_second=5, transient=False) as live:
            while True:
                for frame in drain(bus, 0.1):
                    count.frames += 1
                    if (found := decoder.decode(frame)) is None:
                        count.unknown += 1
                    else:
                        latest[found[0].name] = found
                if count.due():
                    live.update(_signals(latest, f"{header}   {count}"))
    except KeyboardInterrupt:
        pass
    return 0


def _signals(latest: dict[str, tuple[Any, Any]], header: str) -> Group:
    table = Table(box=None, header_style="bold", pad_edge=False)
    for column in ("message", "id", "sender", "signals"):
        table.add_column(column)
    for name in sorted(latest, key=lambda n: latest[n][0].frame_id):
        message, values = latest[name]
        units = {signal.name: signal.unit for signal in message.signals}
        table.add_row(name, _frame_id(message), ", ".join(message.senders), _values(values, units))
    return Group(Text(header), table)
