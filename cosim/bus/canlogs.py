"""CAN logs written by other tools, read frame by frame with python-can's readers.

The formats, by the file's suffix (as python-can's ``can.LogReader`` tells them apart):

- ``.log``: candump's log (``candump -L``: ``(1718000000.123456) can0 123#DEADBEEF``), can-utils;
- ``.blf``: Vector's binary logging format (CANalyzer, CANoe);
- ``.asc``: Vector's ASCII log; its frames are stamped from the ``date`` line of its header
  (python-can reads them relative to it by default: here absolute);
- ``.trc``: PEAK's trace (PCAN-View, PCAN-Explorer), stamped from its ``$STARTTIME``;
- ``.mf4``: ASAM MDF 4 bus logging (``CAN_DataFrame`` channel groups), through python-can's
  reader, which reads it with asammdf (the ``export`` extra);
- ``.csv`` and ``.db``: python-can's own CSV and SQLite logs. They record neither the channel nor
  the CAN FD flags: a frame of more than 8 bytes is taken as CAN FD (it cannot be classic), one of
  up to 8 bytes as classic.

Every frame comes with its time in ns, by the log's clock (``cosim.bus.log_clock``): since the
Unix epoch (candump, MF4, python-can's CSV and SQLite), or the recording's local wall clock, whose
zone the log does not say (ASC, TRC, BLF: logged as if it were UTC, or converted from the zone
given), or from the recording's start where the log has no date. The text formats (candump, ASC,
TRC, CSV) are read line by line (``cosim.bus.log_lines``): their times exactly as written, a line
that is not a frame skipped, counted and named, a file of few frames refused. The binary formats'
times are python-can's float seconds, taken to the microsecond (a float since the epoch keeps
about 0.24 µs); a binary log damaged part way is read up to the damage, with a warning saying how
many frames came before it; one that yields no frame at all is an error. A frame's channel is
named as its log names it (``channel_name``).
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import tzinfo
from pathlib import Path

import can

from cosim.bus.log_clock import CLOCKS, LOCAL, UNKNOWN, UTC, local_to_utc_ns, zone_name
from cosim.bus.log_lines import TEXT_FORMATS, TextLog
from cosim.errors import CosimError
from cosim.extras import require

#: Suffix → the format's name, as ``cosim import`` and ``cosim replay --live`` say it.
FORMATS = {
    ".log": "candump",
    ".blf": "blf",
    ".asc": "asc",
    ".trc": "trc",
    ".mf4": "mf4",
    ".csv": "python-can csv",
    ".db": "python-can sqlite",
}


@dataclass
class LogReading:
    """What reading a CAN log found besides its frames: the zone its times are in, as ``cosim.import``
    records it (``time_zone``: UTC, an IANA zone, ``UNKNOWN`` or ``NO_DATE``), and warnings."""

    time_zone: str = UTC
    warnings: list[str] = field(default_factory=list)


#: The formats whose python-can reader counts channels from 0 where the file counts them from 1
#: (Vector's CAN 1 is python-can's channel 0).
COUNTED_FROM_ZERO = {"blf", "asc"}


def channel_name(frame: can.Message, fmt: str) -> str | None:
    """The channel a frame was recorded on, as its log (and the tool that wrote it) names it:
    candump's interface (``can0``), Vector's channel number from 1 (BLF, ASC), PEAK's bus number
    (TRC), MF4's bus channel; None where the format records none (python-can's CSV and SQLite)."""
    channel = frame.channel
    if channel is None:
        return None
    if fmt in COUNTED_FROM_ZERO and isinstance(channel, int):
        return str(channel + 1)
    return str(channel)


def log_format(path: str | Path) -> str:
    """The format of a CAN log, by its suffix; one line naming the formats for any other file."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        known = ", ".join(f"{name} ({s})" for s, name in FORMATS.items())
        raise CosimError(f"{path}: not a CAN log cosim reads (by its suffix {suffix or '(none)'!r}); it reads {known}")
    return FORMATS[suffix]


def read_frames(path: str | Path, reading: LogReading, zone: tzinfo | None = None) -> Iterator[tuple[can.Message, int]]:
    """The frames of a CAN log in file order, each with its time in ns (since the epoch in UTC, or
    as ``reading.time_zone`` says); ``zone``: the zone a log of local times was recorded in, for
    times in UTC. Warnings go to ``reading``; a file that gives no frame raises one CosimError line."""
    path = Path(path)
    fmt = log_format(path)
    if not path.is_file():
        raise CosimError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    if zone is not None and CLOCKS[fmt] != LOCAL:
        raise CosimError(
            f"--timezone: a {fmt} log's times are seconds since the Unix epoch (UTC) already; the option is for "
            "the local times of ASC, TRC and BLF logs"
        )
    text = TextLog(path, fmt) if fmt in TEXT_FORMATS else None
    frames = text.frames() if text is not None else _binary_frames(path, fmt, reading.warnings)
    shift: int | None = None
    for frame, time_ns in frames:
        if shift is None:
            clock = text.clock if text is not None else CLOCKS[fmt]
            reading.time_zone, shift = _zone(path, clock, zone, time_ns)
        frame.is_fd = frame.is_fd or len(frame.data) > 8  # a format without the flag (python-can's CSV, SQLite)
        yield frame, time_ns - shift
    if text is not None and (skipped := text.warning()) is not None:
        reading.warnings.append(skipped)


def _zone(path: Path, clock: str, zone: tzinfo | None, first_ns: int) -> tuple[str, int]:
    """The zone a log's times are logged in, and what to subtract from them for it: a local clock's
    offset at the first frame (its times count from it, whatever the clocks do later)."""
    if clock != LOCAL:
        if zone is not None:  # a local-time format that turned out to record no date
            raise CosimError(f"--timezone: {path} records no date (times from its start), so no time of day to convert")
        return clock, 0
    if zone is None:
        return UNKNOWN, 0
    return zone_name(zone), first_ns - local_to_utc_ns(first_ns, zone)


def _binary_frames(path: Path, fmt: str, warnings: list[str]) -> Iterator[tuple[can.Message, int]]:
    """A binary log's frames through python-can's reader, with their times to the microsecond."""
    if fmt == "mf4":
        _python_can_mf4()
    count = 0
    try:
        with can.LogReader(path) as reader:
            for frame in reader:
                count += 1
                yield frame, round(frame.timestamp * 1e6) * 1000
    except Exception as error:  # noqa: BLE001 - each reader raises its own kinds on a damaged file
        reason = " ".join(str(error).split()) or type(error).__name__
        if count == 0:
            raise CosimError(f"{path}: cannot read it as a {fmt} log ({reason})") from None
        warnings.append(f"{path}: damaged after {count} frames ({reason}); the frames before it were read")


def _python_can_mf4() -> None:
    """python-can's MF4 reader, with asammdf. The command line imports python-can without its MF4
    support (``cosim.cli._import_can_without_mf4``: asammdf and pandas cost every command half a
    second); a command that reads MF4 imports it again, now with asammdf."""
    require("asammdf", "reading an MF4 log")
    module = sys.modules.get("can.io.mf4")
    if module is not None and getattr(module, "asammdf", None) is None:
        importlib.reload(module)  # the reader class python-can's LogReader holds reads this namespace
