"""Text CAN logs (candump, Vector ASC, PEAK TRC, python-can's CSV) read line by line: python-can's
reader parses each frame, this module times it exactly from its line and reads on past a line the
reader cannot parse.

python-can's text readers stop at the first line they cannot parse (``124#11 22 33`` in a candump
log ends the file there) and give times as float seconds since the epoch, which keep about 0.24 µs
at today's dates (a candump's 0.000200 s comes back as 0.000199936). Here the reader reads the
file's lines through ``_Lines``, which numbers them and keeps the header the reader began with;
when the reader raises on a line, the line is counted (the first named by its number), and a new
reader takes over after it, given the header again. Each frame's time is read from the text of
its line as a decimal (``cosim.bus.log_clock.nanoseconds``), from the date the header records:

- candump: ``(1718000000.000200)``, seconds since the epoch (UTC);
- ASC: the seconds of the line from the header's ``date`` (or the latest ``Begin Triggerblock``
  date; ``timestamps relative``: from the previous event), the recording's local time;
- TRC: the ms offset of the line (the ``O`` column of version 2) from ``$STARTTIME`` (days since
  1899-12-30, the recording's local time, to the µs); a TRC 1.0 trace records no date;
- python-can's CSV: the first column, seconds since the epoch (UTC).

A file whose lines are mostly not frames is refused in one line.
"""

from __future__ import annotations

import logging
import re
from abc import ABC, abstractmethod
from collections.abc import Iterator
from datetime import datetime
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Any

import can

from cosim.bus.log_clock import LOCAL, NO_DATE, UTC, nanoseconds, wall_clock_ns
from cosim.errors import CosimError

#: Lines that are not frames before the first frame, after which a file is refused at once.
NOT_A_LOG_AFTER = 50
#: Lines kept as the header a reader is given again after a line it could not parse.
HEADER_LINES = 1000
#: What python-can's readers raise on a line they cannot parse.
LINE_ERRORS = (ValueError, IndexError, KeyError)


class _Lines:
    """A text log's lines as a python-can reader iterates over them: numbered, each shown to the
    format's clock (``see``), the lines before the first frame kept as the header, which
    ``replay`` gives a new reader again before the lines after the current one."""

    def __init__(self, stream: Any, clock: _Clock) -> None:
        self.stream, self.clock = stream, clock
        self.number, self.text = 0, ""
        self.header: list[str] = []
        self.in_header, self.replaying = True, False
        self._replay: Iterator[str] = iter(())

    def __iter__(self) -> _Lines:
        return self

    def __next__(self) -> str:
        line = next(self._replay, None)
        self.replaying = line is not None
        if line is not None:
            return line
        self.text = next(self.stream)
        self.number += 1
        self.clock.see(self.text, self.number)
        if self.in_header and len(self.header) < HEADER_LINES:
            self.header.append(self.text)
        return self.text

    def framed(self) -> None:
        """The current line was a frame: the header ends before it."""
        if self.in_header:
            self.in_header = False
            if self.header and self.header[-1] is self.text:
                self.header.pop()

    def replay(self) -> None:
        """The next reader reads the header again, then the lines after the current one (which,
        before any frame, is no part of the header)."""
        if self.in_header and self.header and self.header[-1] is self.text:
            self.header.pop()
        self._replay = iter(list(self.header))

    def close(self) -> None:
        """python-can's readers close their file when done; the stream is closed by its owner."""


class _BadHeader(Exception):
    """A header line that says a date or setting this module cannot read (its text names the line)."""


class _Clock(ABC):
    """A text format's times: ``see`` is shown every line of the file, ``time_ns`` gives the time
    of the last one seen (a frame's) in ns, by the clock ``kind`` (log_clock: UTC, LOCAL, NO_DATE)."""

    kind = UTC
    line = ""

    def see(self, line: str, number: int) -> None:
        self.line = line

    @abstractmethod
    def time_ns(self) -> int:
        """The time of the last line seen, in ns (each format's own)."""


class _CandumpClock(_Clock):
    def time_ns(self) -> int:
        return nanoseconds(self.line.split(None, 1)[0][1:-1])


class _CsvClock(_Clock):
    def time_ns(self) -> int:
        return nanoseconds(self.line.split(",", 1)[0])


_ASC_DATE = re.compile(r"\s*(?:date|begin\s+triggerblock)\s+\w+\s+(?P<date>.+?)\s*$", re.IGNORECASE)
_ASC_BASE = re.compile(r"\s*base\s+\w+\s+timestamps\s+(?P<mode>absolute|relative)", re.IGNORECASE)
_MONTHS = {name: i % 12 + 1 for i, name in enumerate("jan feb mar apr may jun jul aug sep oct nov dec".split())}
_MONTHS |= {"mär": 3, "mai": 5, "okt": 10, "dez": 12}  # German month names, as CANoe writes them there
_ASC_FORMATS = (
    "%m %d %I:%M:%S.%f %p %Y",
    "%m %d %I:%M:%S %p %Y",
    "%m %d %H:%M:%S.%f %Y",
    "%m %d %H:%M:%S %Y",
    "%m %d %H:%M:%S.%f %p %Y",
    "%m %d %H:%M:%S %p %Y",
)


def asc_date(text: str) -> datetime | None:
    """An ASC header's date (``Jun 10 08:00:00.250 am 2024``, after the weekday), as written: the
    recording's local time; None if it is not one."""
    month, _, rest = text.partition(" ")
    number = _MONTHS.get(month.lower())
    for form in _ASC_FORMATS if number is not None else ():
        try:
            return datetime.strptime(f"{number:02d} {rest}", form)
        except ValueError:
            continue
    return None


class _AscClock(_Clock):
    kind = NO_DATE

    def __init__(self) -> None:
        self.base = self.elapsed = 0
        self.relative = False

    def see(self, line: str, number: int) -> None:
        self.line = line
        head = line.lstrip()[:1]
        if head.isdigit():
            if self.relative:
                self.elapsed += nanoseconds(line.split(None, 1)[0])
            return
        if (dated := _ASC_DATE.match(line)) is not None:
            when = asc_date(dated.group("date"))
            if when is None:
                example = "Jun 10 08:00:00.250 am 2024"
                raise _BadHeader(f"line {number} {line.strip()!r}: not a date of an ASC log ({example})")
            self.base, self.elapsed, self.kind = wall_clock_ns(when), 0, LOCAL
        elif (base := _ASC_BASE.match(line)) is not None:
            self.relative = base.group("mode").lower() == "relative"

    def time_ns(self) -> int:
        return self.base + (self.elapsed if self.relative else nanoseconds(self.line.split(None, 1)[0]))


#: Days from 1899-12-30 (TRC's $STARTTIME counts from it, as OLE dates do) to the Unix epoch.
_OLE_EPOCH_DAYS = 25569


class _TrcClock(_Clock):
    kind = NO_DATE

    def __init__(self) -> None:
        self.base, self.column = 0, 1

    def see(self, line: str, number: int) -> None:
        self.line = line
        if not line.startswith(";$"):
            return
        key, _, value = line[2:].strip().partition("=")
        if key == "STARTTIME":
            try:
                days = Decimal(value.strip()) - _OLE_EPOCH_DAYS
            except InvalidOperation:
                raise _BadHeader(f"line {number} {line.strip()!r}: $STARTTIME is not a number of days") from None
            # days to about 10 decimals (9 µs): taken to the µs, as PEAK's "Start time" line says it
            self.base, self.kind = int((days * 86_400_000_000).to_integral_value()) * 1000, LOCAL
        elif key == "COLUMNS" and "O" in value.strip().split(","):
            self.column = value.strip().split(",").index("O")

    def time_ns(self) -> int:
        return self.base + nanoseconds(self.line.split()[self.column], scale=6)


class _TrcParseFailures(logging.Handler):
    """python-can's TRC reader logs a line it cannot parse (too few columns) and drops it: counted
    as the other lines that are not frames."""

    def __init__(self, log: TextLog, lines: _Lines) -> None:
        super().__init__(logging.WARNING)
        self.log, self.lines = log, lines

    def emit(self, record: logging.LogRecord) -> None:
        if record.getMessage().startswith("TRCReader: Failed to parse"):
            self.log.count_skipped(self.lines, "too few columns")  # a handler must not raise: refused at the end


_CLOCKS: dict[str, type[_Clock]] = {
    "candump": _CandumpClock,
    "asc": _AscClock,
    "trc": _TrcClock,
    "python-can csv": _CsvClock,
}
_READERS: dict[str, Any] = {
    "candump": can.CanutilsLogReader,
    "asc": can.ASCReader,  # relative_timestamp (its default): python-can parses no date, this module does
    "trc": can.TRCReader,
    "python-can csv": can.CSVReader,
}
TEXT_FORMATS = tuple(_CLOCKS)
#: A frame's line in each text format, as a refusal shows it.
_LOOKS = {
    "candump": "(1718000000.000200) can0 123#DEADBEEF",
    "asc": "0.000200 1  123  Rx   d 4 DE AD BE EF",
    "trc": "1  17535.400 DT 1  0123 Rx -  4  DE AD BE EF",
    "python-can csv": "1718000000.0002,0x123,0,0,0,4,3q2+7w==",
}


class TextLog:
    """A text CAN log of ``fmt`` (``TEXT_FORMATS``), read line by line: ``frames`` gives each frame
    with its time in ns by the log's ``clock`` (UTC, LOCAL or NO_DATE); the lines that are not
    frames are counted in ``skipped``, the first described in ``first_skipped``."""

    def __init__(self, path: Path, fmt: str) -> None:
        self.path, self.fmt = path, fmt
        self._clock = _CLOCKS[fmt]()
        self.frames_read = self.skipped = 0
        self.first_skipped = ""

    @property
    def clock(self) -> str:
        return self._clock.kind

    def frames(self) -> Iterator[tuple[can.Message, int]]:
        with open(self.path, encoding="utf-8-sig", errors="replace") as stream:
            lines = _Lines(stream, self._clock)
            failures = _TrcParseFailures(self, lines)
            logger = logging.getLogger("can.io.trc")
            logger.addHandler(failures)
            try:
                yield from self._read(lines)
            except _BadHeader as error:
                raise CosimError(f"{self.path}: {error}") from None
            finally:
                logger.removeHandler(failures)
        if self.skipped > self.frames_read:
            raise CosimError(
                f"{self.path}: {self.skipped} of its lines are not {self.fmt} frames, against {self.frames_read} that "
                f"are (the first, {self.first_skipped}): not a {self.fmt} log cosim can read (its frames read like "
                f"{_LOOKS[self.fmt]!r})"
            )

    def _read(self, lines: _Lines) -> Iterator[tuple[can.Message, int]]:
        while True:
            try:
                for frame in _READERS[self.fmt](lines):
                    lines.framed()
                    time_ns = self._clock.time_ns()
                    self.frames_read += 1
                    yield frame, time_ns
                return
            except LINE_ERRORS as error:
                if lines.replaying:  # the header itself: nothing after it can be read
                    raise CosimError(f"{self.path}: cannot read it as a {self.fmt} log ({_reason(error)})") from None
                self.skip(lines, _reason(error))
                lines.replay()

    def count_skipped(self, lines: _Lines, reason: str) -> None:
        """The current line is not a frame: counted, the first named."""
        self.skipped += 1
        if self.skipped == 1:
            text = lines.text.strip()
            shown = text if len(text) <= 60 else text[:57] + "..."
            self.first_skipped = f"line {lines.number} {shown!r}: {reason}"

    def skip(self, lines: _Lines, reason: str) -> None:
        """The current line is not a frame: counted; too many before any frame: refused."""
        self.count_skipped(lines, reason)
        if self.frames_read == 0 and self.skipped >= NOT_A_LOG_AFTER:
            raise CosimError(
                f"{self.path}: its first {self.skipped} lines hold no {self.fmt} frame ({self.first_skipped}): "
                f"not a {self.fmt} log cosim can read (its frames read like {_LOOKS[self.fmt]!r})"
            )

    def warning(self) -> str | None:
        """The lines skipped, said in one line (None: none were)."""
        if not self.skipped:
            return None
        lines = "1 line that is not a frame" if self.skipped == 1 else f"{self.skipped} lines that are not frames"
        first = "" if self.skipped == 1 else "the first, "
        read = f"the {self.frames_read} frames around {'it' if self.skipped == 1 else 'them'} were read"
        return f"{self.path.name}: skipped {lines} ({first}{self.first_skipped}); {read}"


def _reason(error: Exception) -> str:
    return " ".join(str(error).split()) or type(error).__name__
