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

Every frame keeps the timestamp its log gives it, seconds since the Unix epoch where the format
records the date (candump, BLF, ASC, TRC, MF4). A log damaged part way is read up to the damage,
with a warning saying how many frames came before it; one that yields no frame at all is an error.
A frame's channel is named as its log names it (``channel_name``).
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can

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


def read_frames(path: str | Path, warnings: list[str]) -> Iterator[can.Message]:
    """The frames of a CAN log in file order, each with its recorded timestamp. Damage part way
    ends the frames with a warning in ``warnings``; a file that gives none raises one CosimError line."""
    path = Path(path)
    fmt = log_format(path)
    if not path.is_file():
        raise CosimError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    options: dict[str, Any] = {"relative_timestamp": False} if fmt == "asc" else {}
    if fmt == "mf4":
        _python_can_mf4()
    count = 0
    try:
        with can.LogReader(path, **options) as reader:
            for frame in reader:
                count += 1
                frame.is_fd = frame.is_fd or len(frame.data) > 8  # a format without the flag (python-can's CSV)
                yield frame
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
